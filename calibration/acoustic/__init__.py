"""The acoustic stage: what the recordings say, before any geometry is fitted.

Each burst's delay against its speaker's reference recording (`delay_estimation`), the times
of flight of a whole session pose by pose (`times_of_flight`), the speed of sound fitted
against the camera's distances to the reference microphone (`speed_of_sound`), and, once the
geometry is known, every microphone's response (`responses`). Nothing here reads an image:
the camera stage (`calibration.camera`) is independent of it, and the fits join the two.
"""
