"""Unit tests of the state machine: the command table and the transition journal."""

from __future__ import annotations

import pytest

from acquisition.daemon.states import (
    ALLOWED,
    WAITING_STATES,
    State,
    StateMachine,
    Transition,
    WrongState,
    check_allowed,
)


def test_every_command_has_a_rule_and_capture_only_while_waiting() -> None:
    assert ALLOWED["capture"] == WAITING_STATES | {State.SESSION_OPEN}
    for state in State:
        check_allowed("status", state)
        check_allowed("ping", state)


@pytest.mark.parametrize(
    ("command", "state", "hint"),
    [
        ("capture", State.IDLE, "micam session start"),
        ("session.stop", State.IDLE, "no session is open"),
        ("session.start", State.WAITING_FOR_POSE, "waiting for the next pose"),
        ("capture", State.PAUSED, "micam session resume"),
        ("capture", State.CAPTURING, "wait for it to finish"),
        ("session.resume", State.REFERENCES, "reference recording"),
        ("redo", State.WAITING_FOR_POSE, "waiting"),
        ("session.abort", State.STOPPING, "closing"),
    ],
)
def test_wrong_state_refusals_say_why(command: str, state: State, hint: str) -> None:
    with pytest.raises(WrongState, match=hint) as caught:
        check_allowed(command, state)
    assert f"cannot {command} while {state.value}" in str(caught.value)


def test_transitions_are_journaled_and_invalid_ones_refused() -> None:
    seen: list[Transition] = []
    machine = StateMachine(seen.append)
    machine.go(State.SESSION_OPEN, "opened")
    machine.go(State.REFERENCES, "next")
    machine.go(State.REFERENCES, "same state: nothing happens")
    machine.go(State.CAPTURING, "go")
    with pytest.raises(RuntimeError, match="no transition from capturing to idle"):
        machine.go(State.IDLE, "skipping stopping")
    assert [(t.previous, t.state) for t in seen] == [
        (State.IDLE, State.SESSION_OPEN), (State.SESSION_OPEN, State.REFERENCES),
        (State.REFERENCES, State.CAPTURING)]
    assert machine.state is State.CAPTURING
