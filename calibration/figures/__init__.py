"""Figures a paper would print, in one style (`style`): the array geometry (`geometry`),
calibration residuals (`residuals`), acoustic maps on camera images (`maps`) and the
source-count study (`study`); the imaging's own figures are in `imaging.figures`."""
