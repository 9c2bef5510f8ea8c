"""The names the page answers to (the Host rule against DNS rebinding) and the Origin rule."""

from __future__ import annotations

import pytest

from micam.web.hosts import (
    HostError,
    ServedHosts,
    parse_allowed,
    parse_authority,
    parse_origin,
    same_origin,
)

LOOPBACK = ServedHosts(8765, "127.0.0.1")


@pytest.mark.parametrize(("text", "parsed"), [
    ("localhost:8765", ("localhost", 8765)),
    ("LocalHost:8765", ("localhost", 8765)),
    ("127.0.0.1", ("127.0.0.1", None)),
    ("[::1]:8765", ("::1", 8765)),
    ("[0:0:0:0:0:0:0:1]:8765", ("::1", 8765)),
    ("[FD00::5]", ("fd00::5", None)),
    ("rig-pc.example:443", ("rig-pc.example", 443)),
    ("", None), (":8765", None), ("localhost:", None), ("localhost:0", None),
    ("localhost:65536", None), ("localhost:+80", None), ("localhost:٨٠", None),
    ("::1", None), ("[::1", None), ("[::1]8765", None), ("[evil]:80", None),
    ("user@localhost:8765", None), ("localhost:8765/x", None), ("evil example", None),
    ("-evil.example", None), ("evil..example", None),
    ("localhost.:8765", None), ("a" * 400, None),
])
def test_a_host_header_is_a_name_or_address_with_an_optional_port(
        text: str, parsed: tuple[str, int | None] | None) -> None:
    assert parse_authority(text) == parsed


@pytest.mark.parametrize("host", ["localhost:8765", "127.0.0.1:8765", "127.3.2.1:8765",
                                  "[::1]:8765", "LOCALHOST:8765"])
def test_loopback_names_are_served_with_the_page_port(host: str) -> None:
    authority = parse_authority(host)
    assert authority is not None and LOOPBACK.serves(authority)


@pytest.mark.parametrize("host", [
    "evil.example:8765",          # a rebinding page's name
    "localhost:8766",             # another port
    "localhost",                  # the default port 80, not the page's
    "10.0.0.5:8765",              # an address the page is not bound to
    "2130706433:8765",            # 127.0.0.1 as one number: a name, not served
])
def test_other_names_and_ports_are_not_served(host: str) -> None:
    authority = parse_authority(host)
    assert authority is not None and not LOOPBACK.serves(authority)


def test_the_bound_address_and_the_allowed_names_are_served() -> None:
    served = ServedHosts(8765, "192.168.1.5", (parse_allowed("rig-pc.example"),
                                               parse_allowed("Proxy.example:8443")))
    for host, answer in (("192.168.1.5:8765", True), ("192.168.1.6:8765", False),
                         ("rig-pc.example", True), ("rig-pc.example:9999", True),
                         ("proxy.example:8443", True), ("proxy.example:8444", False),
                         ("proxy.example", False), ("evil.example:8765", False)):
        authority = parse_authority(host)
        assert authority is not None and served.serves(authority) is answer, host
    assert "rig-pc.example (any port)" in served.names()
    proxied = ServedHosts(8765, "127.0.0.1", (parse_allowed("rig-pc.example:443"),))
    assert proxied.serves(("rig-pc.example", None))  # no port: https's default


def test_bound_to_every_address_any_address_is_served_but_no_name() -> None:
    for bound in ("0.0.0.0", "[::]"):
        served = ServedHosts(8765, bound)
        assert served.serves(("192.168.1.5", 8765)) and served.serves(("fd00::5", 8765))
        assert not served.serves(("192.168.1.5", 80))
        assert not served.serves(("rig-pc.example", 8765))


def test_an_allowed_host_must_be_a_name_with_an_optional_port() -> None:
    assert parse_allowed("[fd00::5]:8765") == ("fd00::5", 8765)
    for bad in ("", "http://rig-pc.example", "rig-pc.example:http", "*.example"):
        with pytest.raises(HostError, match="--allow-host"):
            parse_allowed(bad)


@pytest.mark.parametrize(("origin", "host", "same"), [
    ("http://localhost:8765", ("localhost", 8765), True),
    ("http://LOCALHOST:8765", ("localhost", 8765), True),
    ("http://[::1]:8765", ("::1", 8765), True),
    ("https://rig-pc.example", ("rig-pc.example", None), True),
    ("https://rig-pc.example", ("rig-pc.example", 443), True),
    ("http://rig-pc.example", ("rig-pc.example", 80), True),
    ("https://rig-pc.example:80", ("rig-pc.example", None), False),
    ("http://localhost:8766", ("localhost", 8765), False),
    ("http://evil.example:8765", ("localhost", 8765), False),
    ("null", ("localhost", 8765), False),
    ("file://", ("localhost", 8765), False),
    ("http://localhost:8765/", ("localhost", 8765), False),
    ("http://user@localhost:8765", ("localhost", 8765), False),
    ("http://[::1:8765", ("localhost", 8765), False),
])
def test_an_origin_must_name_the_requests_own_host(
        origin: str, host: tuple[str, int | None], same: bool) -> None:
    parsed = parse_origin(origin)
    assert (parsed is not None and same_origin(parsed, host)) is same
