"""The simulated world: arrays, the rig, poses, sound and light, simulated boards and cameras.

Simulated devices implement the interfaces of `daq` (boards) and `acquisition.contracts.camera`
(cameras), so the real capture code runs on them unchanged.
"""
