"""Unit tests of the message layer: parsing requests, error codes, schemas."""

from __future__ import annotations

import json

import pytest

from acquisition.contracts.protocol import (
    COMMANDS,
    EVENT_ADAPTER,
    CaptureRequest,
    ProgressEvent,
    Reply,
    SessionStartRequest,
    json_schemas,
    utc_now,
)
from acquisition.daemon.server import Refusal, parse_request

LIMIT = 4096


def _frames(obj) -> list[bytes]:
    return [json.dumps(obj).encode()]


def test_valid_request_is_typed() -> None:
    request = parse_request(_frames({"v": 2, "id": "a", "command": "session.start",
                                     "args": {"poses": 4}}), LIMIT)
    assert isinstance(request, SessionStartRequest)
    assert request.args.poses == 4 and request.id == "a"
    assert isinstance(parse_request(_frames({"v": 2, "command": "capture"}), LIMIT),
                      CaptureRequest)


@pytest.mark.parametrize(
    ("frames", "code", "words"),
    [
        ([b"{not json"], "bad_request", "not UTF-8 JSON"),
        ([b"\xff\xfe"], "bad_request", "not UTF-8 JSON"),
        ([b"[1, 2]"], "bad_request", "JSON object, not list"),
        ([b"{}", b"{}"], "bad_request", "2 frames"),
        ([b" " * (LIMIT + 1)], "too_large", f"limit is {LIMIT}"),
        (_frames({"command": "status"}), "bad_request", "v: Field required"),
        (_frames({"v": 3, "command": "status"}), "unsupported_version", "version 3"),
        (_frames({"v": 2, "command": "launch"}), "unknown_command", "'launch'"),
        (_frames({"v": 2, "command": "session.start", "args": {"poses": 0}}), "bad_request",
         "args.poses"),
        (_frames({"v": 2, "command": "session.start", "args": {"resume": "../x"}}),
         "bad_request", "args.resume"),
        (_frames({"v": 2, "command": "capture", "args": {"now": True}}), "bad_request",
         "args.now"),
        (_frames({"v": 2, "command": "status", "id": "x" * 65}), "bad_request", "id"),
    ],
)
def test_bad_requests_are_refused_clearly(frames, code, words) -> None:
    with pytest.raises(Refusal) as caught:
        parse_request(frames, LIMIT)
    assert caught.value.code == code
    assert words in caught.value.message


def test_unknown_command_lists_the_commands() -> None:
    with pytest.raises(Refusal) as caught:
        parse_request(_frames({"v": 2, "command": "nope"}), LIMIT)
    assert all(c in caught.value.message for c in COMMANDS)


def test_schemas_describe_every_message() -> None:
    schemas = json_schemas()
    assert set(schemas) >= {"request", "reply", "event", "status-result"}
    request_schema = json.dumps(schemas["request"])
    assert all(f'"{c}"' in request_schema for c in COMMANDS)
    assert "checkerboard" in json.dumps(schemas["event"])
    json.dumps(schemas)  # plain JSON


def test_events_and_replies_round_trip() -> None:
    event = ProgressEvent(seq=3, time_utc=utc_now(), steps_done=1, steps_total=9, poses_done=0,
                          n_poses=2, step="reference/0")
    assert EVENT_ADAPTER.validate_json(event.model_dump_json()) == event
    reply = Reply(id="r", ok=True, result={"x": 1})
    assert Reply.model_validate_json(reply.model_dump_json()) == reply
