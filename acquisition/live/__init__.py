"""Live mode: the boards scanning without end, the cameras streaming, the latest seconds kept
(`ring`), driven by the daemon (`mode`), recorded (`record`), and shown by clients of the
daemon's protocol (`view`: maps over the frames; `video`: a video file)."""
