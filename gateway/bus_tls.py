"""Mutual TLS where the bus leaves the cell PC.

Inside the PC every process reaches the gateway's router over loopback (``[bus] endpoint``,
``tcp/127.0.0.1:…``). A process on another machine — an operator panel, a recorder, a monitor
in the control room — reaches it over ``[bus] remote_endpoint`` (e.g. ``tls/0.0.0.0:7461``),
where the router listens with **mutual** TLS: both ends present a certificate signed by the
cell's own certificate authority (``[bus] tls_ca_file``), so a machine without one is refused
in the handshake, before it can send a single message, and everything on the link is
encrypted. With ``[bus] credentials_file`` the identity check and the access-control list of
:mod:`gateway.bus_security` apply on top, as on loopback.

A remote machine's cell config names the router's TLS endpoint as its ``endpoint`` (or
``--bus tls/cellpc:7461``) and its own certificate and key in the same three keys; the name
in the endpoint must be one the router's certificate was made for (``verify_name_on_connect``).

``leadthrough bus-certs --out DIR --host cellpc --host 192.168.10.5 --client panel`` makes the
authority and the certificates (EC P-256, each usable as server and as client): ``ca.pem`` for
every machine, ``ca.key`` for nobody (keep it offline: it signs new machines in), and a
``NAME.pem`` / ``NAME.key`` pair per machine. Keys are written mode 600, and a key file that
other users could read is refused, as the credentials file is.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import json
import os
import stat
import sys
from pathlib import Path
from typing import Any

from gateway.errors import EXIT_CONFIG, ConfigError

#: Validity of the certificates ``bus-certs`` makes [days] (the authority's: ten times that).
DEFAULT_DAYS = 825


def check_tls_files(ca_file: str, cert_file: str, key_file: str, where: str) -> None:
    """ConfigError naming the key and the file when one of the three is missing or
    unreadable, or the private key can be read by other users or is not this user's."""
    for name, value in (("tls_ca_file", ca_file), ("tls_cert_file", cert_file),
                        ("tls_key_file", key_file)):  # fmt: skip
        if not value:
            raise ConfigError(f"{where}.{name}: required with a tls/ endpoint")
        try:
            with open(value, "rb") as fh:
                head = fh.read(64)
        except OSError as exc:
            raise ConfigError(f"{where}.{name} {value}: cannot read: {exc.strerror}") from None
        if b"-----BEGIN" not in head:
            raise ConfigError(f"{where}.{name} {value}: not a PEM file")
    st = os.stat(key_file)
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(
            f"{where}.tls_key_file {key_file}: mode {stat.S_IMODE(st.st_mode):04o} lets other "
            f"users read it; it must be readable by the service user only (chmod 600)"
        )
    if st.st_uid != os.geteuid():
        raise ConfigError(
            f"{where}.tls_key_file {key_file}: owned by uid {st.st_uid}, not by this user "
            f"({os.geteuid()})"
        )


def insert_tls(cfg: Any, ca_file: str, cert_file: str, key_file: str) -> None:
    """Mutual TLS on every ``tls/`` link of ``cfg`` (a ``zenoh.Config``): the certificate and
    key are presented both when listening and when connecting; the peer's must be signed by
    the authority, and the name connected to must be in the router's certificate."""
    settings = {
        "root_ca_certificate": str(Path(ca_file).resolve()),
        "listen_certificate": str(Path(cert_file).resolve()),
        "listen_private_key": str(Path(key_file).resolve()),
        "connect_certificate": str(Path(cert_file).resolve()),
        "connect_private_key": str(Path(key_file).resolve()),
        "enable_mtls": True,
        "verify_name_on_connect": True,
    }
    for key, value in settings.items():
        cfg.insert_json5(f"transport/link/tls/{key}", json.dumps(value))


# --- the cell's certificate authority -------------------------------------------------------
def _write_key(path: Path, key: Any) -> None:
    from cryptography.hazmat.primitives import serialization

    data = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as fh:
        os.fchmod(fh.fileno(), 0o600)
        fh.write(data)


def _write_cert(path: Path, cert: Any) -> None:
    from cryptography.hazmat.primitives import serialization

    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def _ca_key_usage(x509: Any) -> Any:
    """Key usage of the authority: it signs certificates (and revocation lists), nothing else."""
    flags = dict.fromkeys(
        ("digital_signature", "content_commitment", "key_encipherment", "data_encipherment",
         "key_agreement", "encipher_only", "decipher_only"),
        False,
    )  # fmt: skip
    return x509.KeyUsage(**flags, key_cert_sign=True, crl_sign=True)


def _alt_name(name: str) -> Any:
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(name))
    except ValueError:
        return x509.DNSName(name)


def make_certificates(
    out: str | Path, hosts: list[str], clients: list[str], days: int = DEFAULT_DAYS
) -> dict[str, Path]:
    """The cell's authority and certificates in ``out`` (module docstring): ``ca.pem``,
    ``ca.key``, ``router.pem``/``router.key`` valid for every name in ``hosts`` (DNS names or
    IP addresses the remote machines connect to), and a pair per name in ``clients``.
    Returns ``{name: path}`` of everything written. ConfigError for bad names."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    if not hosts:
        raise ConfigError("bus-certs: at least one --host (the name remote machines connect to)")
    names = ["router", *clients]
    bad = [n for n in names if not n.replace("-", "").replace("_", "").isalnum()]
    if bad or len(set(names)) != len(names):
        raise ConfigError(f"bus-certs: client names must be distinct words, got {clients}")
    if days < 1:
        raise ConfigError(f"bus-certs: --days {days} must be at least 1")
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "leadthrough cell CA")])
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=10 * days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(_ca_key_usage(x509), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    written = {"ca.pem": root / "ca.pem", "ca.key": root / "ca.key"}
    _write_cert(written["ca.pem"], ca)
    _write_key(written["ca.key"], ca_key)
    for name in names:
        key = ec.generate_private_key(ec.SECP256R1())
        alt = [_alt_name(h) for h in hosts] if name == "router" else [x509.DNSName(name)]
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(alt), critical=False)
            .add_extension(
                x509.ExtendedKeyUsage(
                    [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
                ),
                critical=False,
            )
            .sign(ca_key, hashes.SHA256())
        )
        written[f"{name}.pem"] = root / f"{name}.pem"
        written[f"{name}.key"] = root / f"{name}.key"
        _write_cert(written[f"{name}.pem"], cert)
        _write_key(written[f"{name}.key"], key)
    return written


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.description = (
        "Make the cell's certificate authority and the certificates for mutual TLS where the "
        'bus leaves the cell PC ([bus] remote_endpoint = "tls/0.0.0.0:7461"): ca.pem for every '
        "machine, router.pem/router.key for the gateway, NAME.pem/NAME.key per --client. Keep "
        "ca.key offline."
    )
    p.add_argument("--out", type=Path, required=True, help="folder to write them in")
    p.add_argument("--host", action="append", default=[], required=True,
                   help="a DNS name or IP address remote machines reach the cell PC by "
                   "(repeat for each)")  # fmt: skip
    p.add_argument("--client", action="append", default=[], help="a remote machine's name")
    p.add_argument("--days", type=int, default=DEFAULT_DAYS, help="validity [days]")
    return p


def cli_main(args: argparse.Namespace) -> int:
    try:
        written = make_certificates(args.out, args.host, args.client, args.days)
    except ConfigError as exc:
        print(f"leadthrough {exc}", file=sys.stderr)
        return EXIT_CONFIG
    for name, path in written.items():
        print(f"{name:>14}  {path}")
    print(
        'On the cell PC\'s [bus]: remote_endpoint = "tls/0.0.0.0:7461", tls_ca_file = ca.pem, '
        "tls_cert_file = router.pem, tls_key_file = router.key. On a remote machine: endpoint "
        '= "tls/<host>:7461" and its own NAME.pem / NAME.key.'
    )
    return 0
