"""Certificates of the Zenoh link between sites (automotive zenoh-bridge, docs/zenoh.md): a certificate authority and,
for each site, a key and a certificate signed by it, made with openssl.

    automotive zenoh-certs DIR SITE[=ADDRESS,...] [SITE[=ADDRESS,...] ...]
    automotive zenoh-certs site/certs site-a=10.0.0.2 site-b=10.0.0.3

DIR/ca.pem, DIR/ca.key       the CA (made on the first run, reused afterwards: keep ca.key off the vehicles)
DIR/SITE.pem, DIR/SITE.key   one site's certificate and key

Every certificate is X.509 v3 (rustls, Zenoh's TLS, refuses v1 certificates): the CA with basicConstraints CA:true
and keyCertSign; a site's with digitalSignature (the only usage of an EC key in TLS) and extendedKeyUsage serverAuth
and clientAuth, because a bridge may listen (server) and connect (client), and with mutual TLS the listener checks
the connecting site's certificate too. The subject alternative names are the site's name and the listed addresses: a
bridge that connects to tls/10.0.0.2:7447 checks that the listener's certificate names 10.0.0.2. Keys are EC P-256
(PKCS#8).

The openssl command line drives the work (the cryptography is openssl's; no Python crypto library is needed for
five commands per site).
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from automotive.bus.cli import EXIT_BAD_INPUT, ArgumentParser

PROG = "automotive zenoh-certs"
DEFAULT_DAYS = 825
SITE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9.-]*$")
HOST_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9.-]*$")
CURVE = ["-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256"]


class CertificateError(Exception):
    """What went wrong, in one line (printed after the program's name; exit code 2)."""


def subject_names(site: str, addresses: list[str]) -> str:
    """``DNS:site,IP:10.0.0.2,DNS:host.example``: the site's name and its addresses, as subjectAltName says them."""
    names = [f"DNS:{site}"]
    for address in addresses:
        try:
            names.append(f"IP:{ipaddress.ip_address(address)}")
        except ValueError:
            if not HOST_NAME.match(address):
                raise CertificateError(f"site {site}: '{address}' is not an IP address or host name") from None
            names.append(f"DNS:{address}")
    return ",".join(names)


def parse_site(spec: str) -> tuple[str, str]:
    """``site-a=10.0.0.2,10.0.0.4`` -> (``site-a``, its subject alternative names)."""
    site, _, addresses = spec.partition("=")
    if not SITE_NAME.match(site):
        raise CertificateError(f"site name '{site}': expected letters, digits, '.' and '-'")
    return site, subject_names(site, [address for address in addresses.split(",") if address])


def openssl(what: str, *args: str, stdin: str | None = None) -> None:
    result = subprocess.run(["openssl", *args], input=stdin, capture_output=True, text=True)
    if result.returncode != 0:
        detail = next((line for line in result.stderr.splitlines() if line.strip()), "no message")
        raise CertificateError(f"openssl could not make {what} ({detail.strip()})")


def make_key(path: Path, what: str) -> None:
    openssl(what, "genpkey", *CURVE, "-out", str(path))
    path.chmod(0o600)


def make_ca(folder: Path, days: int) -> bool:
    """The CA in ``folder`` unless both its files are there; True when made now."""
    certificate, key = folder / "ca.pem", folder / "ca.key"
    if certificate.is_file() and key.is_file():
        return False
    make_key(key, f"the CA key in {folder}")
    openssl("the CA", "req", "-x509", "-new", "-key", str(key), "-sha256", "-days", str(days),
            "-subj", "/CN=automotive zenoh CA", "-addext", "basicConstraints=critical,CA:true",
            "-addext", "keyUsage=critical,keyCertSign,cRLSign", "-addext", "subjectKeyIdentifier=hash",
            "-out", str(certificate))
    return True


def make_site(folder: Path, site: str, names: str, days: int) -> None:
    key, certificate = folder / f"{site}.key", folder / f"{site}.pem"
    make_key(key, f"the key of {site}")
    with tempfile.TemporaryDirectory(prefix="zenoh-certs-") as scratch:
        request, extensions = Path(scratch) / "site.csr", Path(scratch) / "site.ext"
        extensions.write_text("\n".join(["basicConstraints=critical,CA:false", "keyUsage=critical,digitalSignature",
                                         "extendedKeyUsage=serverAuth,clientAuth", f"subjectAltName={names}",
                                         "subjectKeyIdentifier=hash", "authorityKeyIdentifier=keyid"]) + "\n")
        openssl(f"the signing request of {site}", "req", "-new", "-key", str(key), "-subj", f"/CN={site}",
                "-out", str(request))
        openssl(f"the certificate of {site}", "x509", "-req", "-in", str(request), "-CA", str(folder / "ca.pem"),
                "-CAkey", str(folder / "ca.key"), "-CAcreateserial", "-sha256", "-days", str(days),
                "-extfile", str(extensions), "-out", str(certificate))


def make(folder: Path, specs: list[str], days: int = DEFAULT_DAYS) -> list[str]:
    """Make the CA (if missing) and each site's key and certificate in ``folder``; the lines saying what was made."""
    sites = [parse_site(spec) for spec in specs]  # every argument checked before anything is written
    if shutil.which("openssl") is None:
        raise CertificateError("openssl is not installed (apt-get install openssl)")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise CertificateError(f"cannot create the folder {folder} ({error.strerror})") from None
    if not os.access(folder, os.W_OK):
        raise CertificateError(f"cannot write into the folder {folder}")
    said = []
    if make_ca(folder, days):
        said.append(f"made the CA: {folder / 'ca.pem'} (key {folder / 'ca.key'})")
    for site, names in sites:
        make_site(folder, site, names, days)
        said.append(f"made {folder / (site + '.pem')} (key {folder / (site + '.key')}) for {names}")
    return said


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="where the CA and the sites' files go (made if missing)")
    parser.add_argument("sites", nargs="+", metavar="SITE[=ADDRESS,...]",
                        help="a site's name and the addresses (or host names) its bridge listens on")
    parser.add_argument("--days", type=int, default=DEFAULT_DAYS,
                        help=f"validity of new certificates in days (default {DEFAULT_DAYS})")
    args = parser.parse_args(argv)
    if args.days < 1:
        parser.error(f"--days {args.days}: expected a positive number")
    try:
        for line in make(args.folder, args.sites, args.days):
            print(line)
    except CertificateError as error:
        print(f"{PROG}: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0


if __name__ == "__main__":
    sys.exit(main())
