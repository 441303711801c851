"""Mutual TLS where the bus leaves the cell PC (``gateway/bus_tls.py``), over real zenoh
sessions: a machine with a certificate of the cell's authority reaches the router's TLS
endpoint; one with another authority's certificate, or none, is refused in the handshake and
never delivers a message; the loopback endpoint works beside it as before."""

from __future__ import annotations

import os
import time

import pytest

from gateway.bus import BusConfig, open_client, open_router
from gateway.bus_tls import make_certificates
from gateway.errors import ConfigError, LinkTimeoutError
from sim_bridge.harness import free_port

SETTLE_S = 0.4


@pytest.fixture
def pki(tmp_path):
    """The cell's authority (router for 127.0.0.1, client 'panel') and a foreign one."""
    make_certificates(tmp_path / "cell", ["127.0.0.1"], ["panel"])
    make_certificates(tmp_path / "other", ["127.0.0.1"], ["intruder"])
    return tmp_path


def _files(root, name, ca="cell"):
    return {
        "tls_ca_file": str(root / ca / "ca.pem"),
        "tls_cert_file": str(root / ca / f"{name}.pem"),
        "tls_key_file": str(root / ca / f"{name}.key"),
    }


@pytest.fixture
def cell_router(pki, port):
    remote = free_port()
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{port}", remote_endpoint=f"tls/127.0.0.1:{remote}",
                    **_files(pki, "router"))  # fmt: skip
    session = open_router(bus)
    got: list[bytes] = []
    sub = session.declare_subscriber("lt/probe", lambda s: got.append(s.payload.to_bytes()))
    yield bus, remote, got
    sub.undeclare()
    session.close()


def _put_from(bus: BusConfig, payload: bytes) -> None:
    session = open_client(bus, connect_timeout_s=2.0)
    try:
        time.sleep(SETTLE_S)
        session.put("lt/probe", payload)
        time.sleep(SETTLE_S)
    finally:
        session.close()


def test_a_machine_of_the_cell_reaches_the_router_over_mutual_tls(pki, cell_router):
    bus, remote, got = cell_router
    panel = BusConfig(endpoint=f"tls/127.0.0.1:{remote}", **_files(pki, "panel"))
    _put_from(panel, b"from the panel")
    assert got == [b"from the panel"]
    _put_from(BusConfig(endpoint=bus.endpoint), b"from loopback")  # the PC's own link
    assert got == [b"from the panel", b"from loopback"]


@pytest.mark.parametrize(
    "who",
    ["another authority's certificate", "the authority's own certificate as a client"],
)
def test_a_machine_without_the_cells_certificate_is_refused(pki, cell_router, who):
    _, remote, got = cell_router
    if who.startswith("another"):
        files = _files(pki, "intruder", ca="other")
        files["tls_ca_file"] = str(pki / "cell" / "ca.pem")  # it trusts the cell; not trusted
    else:
        files = _files(pki, "panel")
        files["tls_cert_file"] = str(pki / "other" / "ca.pem")  # a certificate, wrong key
        files["tls_key_file"] = str(pki / "other" / "ca.key")
    intruder = BusConfig(endpoint=f"tls/127.0.0.1:{remote}", **files)
    with pytest.raises(LinkTimeoutError, match="TLS handshake"):
        _put_from(intruder, b"forged")
    assert got == []


def test_plain_tcp_to_the_tls_endpoint_delivers_nothing(cell_router):
    _, remote, got = cell_router
    with pytest.raises(LinkTimeoutError):
        _put_from(BusConfig(endpoint=f"tcp/127.0.0.1:{remote}"), b"plain")
    assert got == []


def test_bad_tls_settings_are_refused_naming_the_key(pki, port):
    files = _files(pki, "router")
    with pytest.raises(ConfigError, match=r"remote_endpoint.*mutual TLS"):
        BusConfig(endpoint=f"tcp/127.0.0.1:{port}", remote_endpoint="tcp/0.0.0.0:7461")
    with pytest.raises(ConfigError, match="tls_key_file: required"):
        open_router(BusConfig(endpoint=f"tcp/127.0.0.1:{port}",
                              remote_endpoint=f"tls/127.0.0.1:{free_port()}",
                              **{**files, "tls_key_file": ""}))  # fmt: skip
    os.chmod(files["tls_key_file"], 0o644)
    with pytest.raises(ConfigError, match=r"tls_key_file .*router.key: mode 0644"):
        open_router(BusConfig(endpoint=f"tcp/127.0.0.1:{port}",
                              remote_endpoint=f"tls/127.0.0.1:{free_port()}", **files))  # fmt: skip
    with pytest.raises(ConfigError, match=r"tls_cert_file .*: not a PEM file"):
        bad = pki / "cell" / "bad.pem"
        bad.write_text("not a certificate\n")
        open_client(BusConfig(endpoint=f"tls/127.0.0.1:{port}",
                              **{**files, "tls_cert_file": str(bad)}))  # fmt: skip


def test_the_keys_are_private_and_the_router_certificate_names_its_hosts(tmp_path):
    written = make_certificates(tmp_path, ["cellpc", "192.168.10.5"], ["panel", "recorder"])
    pairs = [f"{n}.{e}" for n in ("ca", "router", "panel", "recorder") for e in ("pem", "key")]
    assert sorted(written) == sorted(pairs)
    for name, path in written.items():
        if name.endswith(".key"):
            assert os.stat(path).st_mode & 0o777 == 0o600, name
    from cryptography import x509

    cert = x509.load_pem_x509_certificate(written["router.pem"].read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.DNSName) == ["cellpc"]
    assert [str(a) for a in san.get_values_for_type(x509.IPAddress)] == ["192.168.10.5"]
    with pytest.raises(ConfigError, match="at least one --host"):
        make_certificates(tmp_path / "x", [], [])
