"""Bad input to `micam daq trace`: a truncated, foreign, corrupt, huge or garbage file is one
line naming the file and what is wrong (exit 2), never a traceback; reads are bounded and the
file streamed (the memory a decode takes does not grow with the capture)."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from daq.usb.bringup import TraceError, decode, read_transfers
from micam.cli import main

from .usb_capture import usbmon_header, usbpcap_header, write_pcap, write_pcapng

LONG = os.environ.get("MICAM_LONG_TESTS") == "1"
EXAMPLES = int(os.environ.get("MICAM_FUZZ_EXAMPLES", "5000" if LONG else "150"))
COMMAND = bytes([20, 0, 0, 0, 0x00, 0x20]) + bytes(58)


def _records(mmapped: bool = False) -> list[tuple[float, bytes]]:
    """One R_SINGLE_WORD_LB and its reply, as usbmon's four events."""
    def ev(urb: int, kind: str, ep: int, status: int, length: int, data: bytes) -> bytes:
        return usbmon_header(urb, kind, 3, ep, 5, 1, None, bool(data), 100.0, status, length,
                             len(data), mmapped) + data
    return [(100.0, ev(1, "S", 0x01, -115, 64, COMMAND)), (100.001, ev(1, "C", 0x01, 0, 64, b"")),
            (100.002, ev(2, "S", 0x81, -115, 64, b"")),
            (100.003, ev(2, "C", 0x81, 0, 2, b"\x00\x04"))]


def _fails(argv: list[str], capsys: pytest.CaptureFixture[str], *needles: str) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("micam: error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in err, err
    return err


def test_a_truncated_capture_is_named_as_truncated(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    for write, name in ((write_pcap, "cut.pcap"), (write_pcapng, "cut.pcapng")):
        whole = write(tmp_path / name, 189, _records()).read_bytes()
        for cut in (len(whole) - 3, len(whole) - 40, 30):
            (tmp_path / name).write_bytes(whole[:cut])
            _fails(["daq", "trace", "show", str(tmp_path / name)], capsys,
                   f"{tmp_path / name} is truncated")
    (tmp_path / "head.pcap").write_bytes(whole[:10])
    _fails(["daq", "trace", "show", str(tmp_path / "head.pcap")], capsys, "is truncated")


def test_a_capture_of_another_link_type_is_refused(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    path = write_pcap(tmp_path / "eth.pcap", 1, [(1.0, bytes(60))])
    _fails(["daq", "trace", "show", str(path)], capsys, "link type 1 (Ethernet), not of USB",
           "usbmon")
    path = write_pcapng(tmp_path / "eth.pcapng", 113, [(1.0, bytes(60))])
    _fails(["daq", "trace", "show", str(path)], capsys, "link type 113 (Linux cooked)")


def test_a_record_claiming_a_huge_length_is_refused_before_it_is_read(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A corrupt caplen of 2 GiB: no 2 GiB read, a one-line error."""
    path = write_pcap(tmp_path / "huge.pcap", 220, _records(True))
    data = bytearray(path.read_bytes())
    struct.pack_into("<I", data, 24 + 8, 0x7FFF_FFFF)  # the first record's incl_len
    path.write_bytes(bytes(data))
    _fails(["daq", "trace", "show", str(path)], capsys, "claims 2147483647 bytes",
           "the file is corrupt")


def test_corrupt_usb_headers_are_named(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    short = write_pcap(tmp_path / "short.pcap", 220, [(1.0, bytes(20))])
    _fails(["daq", "trace", "show", str(short)], capsys,
           "record 0 has 20 bytes, fewer than the 64-byte usbmon header")
    not_usbmon = write_pcap(tmp_path / "x.pcap", 189, [(1.0, b"\x00" * 8 + b"X" + bytes(39))])
    _fails(["daq", "trace", "show", str(not_usbmon)], capsys, "record 0 is not a usbmon event")
    bad_len = usbpcap_header(1, 0, 9, False, 1, 5, 0x01, 3, 0)
    bad_len = struct.pack("<H", 900) + bad_len[2:]
    pcap = write_pcap(tmp_path / "u.pcap", 249, [(1.0, bad_len)])
    _fails(["daq", "trace", "show", str(pcap)], capsys, "USBPcap header length of 900 bytes")


def test_garbage_empty_missing_and_directory_inputs(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "garbage").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    _fails(["daq", "trace", "show", str(tmp_path / "garbage")], capsys,
           "neither a pcap or pcapng capture nor a micam transfer trace", "89504e47")
    (tmp_path / "empty").write_bytes(b"")
    _fails(["daq", "trace", "show", str(tmp_path / "empty")], capsys, "is empty")
    _fails(["daq", "trace", "show", str(tmp_path / "nothing")], capsys, "cannot read")
    _fails(["daq", "trace", "diff", str(tmp_path), str(tmp_path)], capsys, "is a directory")


def test_a_damaged_micam_trace_names_the_line(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    good = {"t": 0.1, "wall": 1.0, "dev": "x", "kind": "bulk", "dir": "out", "ep": 1,
            "len": 64, "status": "ok", "data": COMMAND.hex()}
    path = tmp_path / "t.jsonl"
    cases = {
        '{"t": 0.1,': "line 2 is not JSON",
        json.dumps({**good, "ep": 4096}): "line 2: ep: Input should be less than or equal",
        json.dumps({**good, "data": "zz"}): "line 2: data: String should match pattern",
        json.dumps({**good, "kind": "iso"}): "line 2: kind:",
        json.dumps({**good, "t": -1}): "line 2: t:",
        "{" + " " * (5 * 2**20) + "}": "line 2 is longer than 4 MiB",
    }
    for line, needle in cases.items():
        path.write_text(json.dumps(good) + "\n" + line + "\n")
        _fails(["daq", "trace", "show", str(path)], capsys, needle)


def test_bad_options_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_pcap(tmp_path / "ok.pcap", 189, _records())
    for argv in (["--device", "1"], ["--device", "1:300"], ["--serial", "x"], ["--from", "-1"],
                 ["--to", "nan"]):
        with pytest.raises(SystemExit) as exit_:
            main(["daq", "trace", "show", str(path), *argv])
        assert exit_.value.code == 2
    capsys.readouterr()
    _fails(["daq", "trace", "show", str(path), "--from", "2", "--to", "1"], capsys,
           "--to 1.0 is before --from 2.0")


@settings(max_examples=EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_a_damaged_capture_never_raises_anything_but_a_trace_error(
        tmp_path_factory: pytest.TempPathFactory, data: st.DataObject) -> None:
    """Any capture with bytes changed, cut or inserted decodes or fails with TraceError."""
    linktype = data.draw(st.sampled_from([189, 220, 249]))
    write = data.draw(st.sampled_from([write_pcap, write_pcapng]))
    if linktype == 249:
        records = [(1.0, usbpcap_header(7, 0, 9, False, 1, 5, 0x01, 3, 64) + COMMAND),
                   (1.1, usbpcap_header(7, 0, 9, True, 1, 5, 0x01, 3, 0))]
    else:
        records = _records(linktype == 220)
    path = write(tmp_path_factory.mktemp("fuzz") / "c", linktype, records)
    raw = bytearray(path.read_bytes())
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(raw) - 1))
        op = data.draw(st.sampled_from(["set", "cut", "insert"]))
        if op == "set":
            raw[at] = data.draw(st.integers(0, 255))
        elif op == "cut":
            del raw[at: at + data.draw(st.integers(1, 16))]
        else:
            raw[at:at] = data.draw(st.binary(min_size=1, max_size=16))
        if not raw:
            raw = bytearray(b"\0")
    path.write_bytes(bytes(raw))
    try:
        list(decode(read_transfers(path)))
    except TraceError:
        pass


def test_decoding_a_large_capture_streams_it(tmp_path: Path) -> None:
    """A 64 MiB capture of 64 KiB stream transfers: the peak memory of the process that
    decodes it grows by far less than the file (the records are never held together)."""
    block = bytes(65536)
    path = tmp_path / "big.pcap"
    with path.open("wb") as f:
        f.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, 220))
        for i in range(1024):
            for kind, data in (("S", b""), ("C", block)):
                rec = usbmon_header(i, kind, 3, 0x82, 5, 1, None, bool(data), 1.0 + i / 1e4,
                                    0 if kind == "C" else -115, 65536, len(data), True) + data
                f.write(struct.pack("<IIII", 1, i, len(rec), len(rec)) + rec)
    assert path.stat().st_size > 64 * 2**20
    script = (
        "import sys\n"
        "from pathlib import Path\n"
        "from daq.usb.bringup import decode, read_transfers\n"
        "def hwm():\n"
        "    for line in open('/proc/self/status'):\n"
        "        if line.startswith('VmHWM:'):\n"
        "            return int(line.split()[1])\n"
        "before = hwm()\n"
        "events = [e for e in decode(read_transfers(Path(sys.argv[1]))) if e.kind != 'poll']\n"
        "print(len(events), hwm() - before)\n")
    out = subprocess.run([sys.executable, "-c", script, str(path)], capture_output=True,
                         text=True, check=True).stdout.split()
    assert out[0] == "1"  # one stream run
    assert int(out[1]) < 16 * 1024, f"peak memory grew by {out[1]} KiB"
