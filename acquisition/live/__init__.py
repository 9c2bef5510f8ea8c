"""Live mode: the boards scanning without end, the cameras streaming, the latest seconds kept
(`ring`), driven by the daemon (`mode`) and recorded (`record`). Clients of the daemon's
protocol show it: `micam.live_feed` (the stream), imaging's `live_frames` and
`live_draw` (maps over the frames) and `micam live video` (a video file)."""
