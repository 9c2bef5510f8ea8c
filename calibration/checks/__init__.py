"""The calibration's checks: the capture's and the fit's mistakes, and whether a result holds.

Mistakes of the wiring and the playback found in the recordings (`capture_checks`; a speaker
driven into distortion, `distortion`), of the microphone cables found against the array's
nominal layout (`layout_check`), of swapped speakers, a misplaced reference microphone and
moved poses found in the camera-frozen fit's residuals (`fit_checks`), a reflector close to a
microphone found in the joint fit's responses (`response_checks`); a result
whose model does not fit its data refused (`plausibility`); and whether a covariance
describes the errors against a truth (`coverage`). The images' own mistakes are the camera
stage's (`calibration.camera.image_checks`), which its fit calls. Each judges against the
same session, and each imports the stages it checks, never the reverse.
"""
