"""The daemon's state machine: which state follows which, and which command each state accepts.

    idle -> session_open -> references -> reference_microphone -> waiting_for_pose
                             ^    \\            ^    \\              ^    \\
                             |     capturing --+     capturing ---+     capturing
    any session state -> paused (back by resume) ; any session state -> stopping -> idle
    idle <-> live (live mode: the boards scanning without end, no session open)

`references`, `reference_microphone` and `waiting_for_pose` wait for the operator's `capture`
of the current step (its instruction says what to set up); `capturing` records it. Every
transition goes through `StateMachine.go`, which refuses one that is not in the table (a bug,
never an operator error) and hands each accepted one to the journal callback.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from acquisition.contracts.instructions import InstructionKind


class State(StrEnum):
    IDLE = "idle"
    SESSION_OPEN = "session_open"
    REFERENCES = "references"
    REFMIC = "reference_microphone"
    WAITING_FOR_POSE = "waiting_for_pose"
    CAPTURING = "capturing"
    PAUSED = "paused"
    STOPPING = "stopping"
    LIVE = "live"


WAITING_STATES = frozenset({State.REFERENCES, State.REFMIC, State.WAITING_FOR_POSE})
SESSION_STATES = frozenset(State) - {State.IDLE, State.LIVE}

WAITING_STATE_FOR: dict[InstructionKind, State] = {
    InstructionKind.REFERENCE_AT_SPEAKER: State.REFERENCES,
    InstructionKind.REFERENCE_ON_STAND: State.REFMIC,
    InstructionKind.RIG_AT_POSE: State.WAITING_FOR_POSE,
}

_TRANSITIONS: dict[State, frozenset[State]] = {
    State.IDLE: frozenset({State.SESSION_OPEN, State.LIVE}),
    State.LIVE: frozenset({State.IDLE}),
    State.SESSION_OPEN: WAITING_STATES | {State.STOPPING},
    State.CAPTURING: WAITING_STATES | {State.PAUSED, State.STOPPING},
    State.PAUSED: WAITING_STATES | {State.STOPPING},
    State.STOPPING: frozenset({State.IDLE}),
    **{s: (WAITING_STATES - {s}) | {State.CAPTURING, State.PAUSED, State.STOPPING}
       for s in WAITING_STATES},
}

_ANY = frozenset(State)
ALLOWED: dict[str, frozenset[State]] = {
    "ping": _ANY,
    "status": _ANY,
    "sessions.list": _ANY,
    "describe": _ANY,
    "previews": _ANY,
    "session.report": _ANY,
    "session.file": _ANY,
    "session.start": frozenset({State.IDLE}),
    "session.stop": SESSION_STATES - {State.STOPPING},
    "session.abort": SESSION_STATES - {State.STOPPING},
    "session.pause": WAITING_STATES | {State.CAPTURING},
    "session.resume": frozenset({State.PAUSED}),
    "capture": WAITING_STATES | {State.SESSION_OPEN},  # a go given while the session opens
    "redo": frozenset({State.CAPTURING}),
    "live.start": frozenset({State.IDLE}),  # never while a calibration session runs
    "live.stop": frozenset({State.LIVE}),
    "live.record": frozenset({State.LIVE}),
}
"""The states in which each command is accepted (the daemon may still refuse for a reason
that is not the state, e.g. stop before the references are recorded)."""

_WHY_NOT: dict[State, str] = {
    State.IDLE: "no session is open; start one with `micam session start`",
    State.LIVE: "the daemon is in live mode; leave it with `micam live stop` first",
    State.SESSION_OPEN: "the session is opening; try again in a moment",
    State.CAPTURING: "a step is being captured; wait for it to finish",
    State.PAUSED: "the session is paused; continue with `micam session resume`",
    State.STOPPING: "the session is closing",
    State.REFERENCES: "the daemon is waiting for a reference recording to be captured",
    State.REFMIC: "the daemon is waiting for the reference-microphone image to be captured",
    State.WAITING_FOR_POSE: "the daemon is waiting for the next pose to be captured",
}


class WrongState(Exception):
    """A command that the current state does not accept; the message says why and what to do."""


def check_allowed(command: str, state: State) -> None:
    """Raise WrongState unless `command` is accepted in `state`."""
    if state not in ALLOWED[command]:
        raise WrongState(f"cannot {command} while {state.value}: {_WHY_NOT[state]}")


@dataclass(frozen=True)
class Transition:
    previous: State
    state: State
    reason: str


class StateMachine:
    """Holds the current state; `go` validates a transition and reports it to `on_transition`."""

    def __init__(self, on_transition: Callable[[Transition], None]) -> None:
        self._state = State.IDLE
        self._on_transition = on_transition

    @property
    def state(self) -> State:
        return self._state

    def go(self, state: State, reason: str) -> None:
        """Move to `state` (nothing happens if already there)."""
        if state is self._state:
            return
        if state not in _TRANSITIONS[self._state]:
            raise RuntimeError(f"bug: no transition from {self._state.value} to {state.value} "
                               f"({reason})")
        transition = Transition(self._state, state, reason)
        self._state = state
        self._on_transition(transition)
