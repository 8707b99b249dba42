"""Certificates for TLS tests, made with the openssl command line: a self-signed one, a CA of the test's own, and
certificates it issues, each for 127.0.0.1 (the tests' servers listen on loopback).

    ca = certificate_authority(tmp_path / "ca-a")
    cert, key = ca.issue(tmp_path / "replica-0")
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

HOST = "127.0.0.1"
NEW_KEY = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]


def _openssl(*args: str) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is not installed (apt-get install openssl)")
    subprocess.run(["openssl", *args], check=True, capture_output=True, timeout=30)


def self_signed(folder: Path) -> tuple[Path, Path]:
    """A self-signed certificate for 127.0.0.1 and its key: (tls.crt, tls.key) in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    cert, key = folder / "tls.crt", folder / "tls.key"
    _openssl(
        *("req", "-x509", *NEW_KEY, "-keyout", str(key), "-out", str(cert), "-days", "1", "-subj", f"/CN={HOST}"),
        *("-addext", f"subjectAltName=IP:{HOST}"),
    )
    return cert, key


@dataclass(frozen=True)
class CertificateAuthority:
    cert: Path  # what a peer CA bundle holds
    key: Path

    def issue(self, folder: Path) -> tuple[Path, Path]:
        """A certificate for 127.0.0.1 signed by this CA, and its key: (tls.crt, tls.key) in `folder`."""
        folder.mkdir(parents=True, exist_ok=True)
        cert, key, request, extensions = (folder / n for n in ("tls.crt", "tls.key", "tls.csr", "ext.cnf"))
        extensions.write_text(f"subjectAltName=IP:{HOST}\nbasicConstraints=critical,CA:FALSE\n")
        _openssl("req", *NEW_KEY, "-keyout", str(key), "-out", str(request), "-subj", f"/CN={HOST}")
        _openssl(
            *("x509", "-req", "-in", str(request), "-CA", str(self.cert), "-CAkey", str(self.key)),
            *("-CAcreateserial", "-out", str(cert), "-days", "1", "-extfile", str(extensions)),
        )
        return cert, key


def certificate_authority(folder: Path) -> CertificateAuthority:
    """A CA of its own in `folder` (ca.crt, ca.key), named after the folder."""
    folder.mkdir(parents=True, exist_ok=True)
    cert, key = folder / "ca.crt", folder / "ca.key"
    _openssl(
        *("req", "-x509", *NEW_KEY, "-keyout", str(key), "-out", str(cert), "-days", "1"),
        *("-subj", f"/CN=test CA {folder.name}", "-addext", "basicConstraints=critical,CA:TRUE"),
        *("-addext", "keyUsage=critical,keyCertSign,cRLSign"),
    )
    return CertificateAuthority(cert, key)
