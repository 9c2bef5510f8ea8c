"""The camera stage: what the checkerboard images say, before any sound is used.

The board and its corners in an image (`corners`), the images' own mistakes (`image_checks`,
its measures in `image_measures`), each camera's intrinsics, board poses and transform from
camera 0 (`camera_calibration`) with each camera's corner noise (`corner_noise`) and the
board's bow (`board_bow`), and from the board poses the speakers' and the reference
microphone's positions in the camera-0 frame (`speakers`). Nothing here reads a recording:
the acoustic stage (`calibration.acoustic`) is independent of it, and the fits join the two.
"""
