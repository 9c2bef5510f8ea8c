"""The mistakes a real capture holds, made by the simulated world where a lab makes them.

`micam simulate --mistake NAME[=ARGS]` asks for them (spec: the names and their arguments);
the planner fixes each for the session from its seed and writes down what was done (the
records in truth.json's "mistakes"); the world's layers consult the resulting `Mistakes`
(plan): the bench for the cables, capsules, speakers and input stages, the operator for the
rig and the reference microphone, the cameras for the scene and the codec. The capture itself
stays the real sequencer on the simulated hardware, and its configuration the nominal one: a
swapped cable is a fact of the world, not of what the session says.

The package itself exports only the names (spec, light: `micam simulate --help` lists them
without loading the world); the world's layers import `.plan` and `.planner`.
"""

from .spec import KINDS, MistakeKind, parse_mistake

__all__ = ["KINDS", "MistakeKind", "parse_mistake"]
