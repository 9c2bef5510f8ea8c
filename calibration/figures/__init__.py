"""Figures a paper would print, in one style (`style`): the array geometry (`geometry`),
calibration residuals (`residuals`), acoustic maps on camera images (`maps`), the
source-count study (`study`) and imaging evaluations (`evaluation`)."""
