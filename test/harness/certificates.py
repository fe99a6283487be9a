# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
Certificates for the Zenoh link's tests and benchmark, made by openssl as the docs say.

    with certificates.Sites({'master': 'DNS:master-site', 'arm': 'IP:10.231.7.2'}) as sites:
        sites.ca, sites['arm'].certificate, sites['arm'].private_key, sites.strangers['arm']

A root CA, and for each site a P-256 key and a certificate the CA signed, its common name the
site's name and its subject alternative name the one given (the listening site's address: the
connecting site checks it). `strangers[site]` is a key and a self-signed certificate with the
site's common name and alternative name: what an intruder who copied a site's names but holds
no signed certificate has (doc/remote-teleoperation.md gives the commands). Everything is in a
temporary directory, deleted at the end of the `with` block.
"""
import pathlib
import shutil
import subprocess
import tempfile
from typing import NamedTuple

CURVE = ('-newkey', 'ec', '-pkeyopt', 'ec_paramgen_curve:prime256v1', '-nodes')
CA_NAME = 'kraft-teleop-ca'


class Site(NamedTuple):
    """A site's certificate and private key (PEM files)."""

    certificate: str
    private_key: str


def _openssl(directory, *args):
    subprocess.run(['openssl', *args], cwd=directory, check=True, capture_output=True,
                   timeout=60)


def openssl_missing():
    """Return why certificates cannot be made here, or '' if openssl is on the PATH."""
    return '' if shutil.which('openssl') else 'openssl is not on the PATH'


class Sites:
    """Context manager: a root CA, a signed certificate per site, a stranger per site."""

    def __init__(self, alternative_names):
        """Make certificates for {site: subjectAltName} once entered."""
        self.alternative_names = dict(alternative_names)
        self._directory = None
        self.sites = {}
        self.strangers = {}

    def __enter__(self):
        """Write the files; return self."""
        self._directory = tempfile.TemporaryDirectory(prefix='kmd_certificates_')
        directory = pathlib.Path(self._directory.name)
        try:
            self._make(directory)
        except BaseException:
            self._directory.cleanup()
            raise
        return self

    def _make(self, directory):
        _openssl(directory, 'req', '-x509', *CURVE, '-keyout', 'ca.key', '-out', 'ca.pem',
                 '-days', '2', '-subj', f'/CN={CA_NAME}',
                 '-addext', 'basicConstraints=critical,CA:TRUE',
                 '-addext', 'keyUsage=critical,keyCertSign,cRLSign')
        self.ca = str(directory / 'ca.pem')
        for name, alternative in self.alternative_names.items():
            (directory / f'{name}.ext').write_text(
                f'subjectAltName={alternative}\nextendedKeyUsage=serverAuth,clientAuth\n')
            _openssl(directory, 'req', *CURVE, '-keyout', f'{name}.key', '-out', f'{name}.csr',
                     '-subj', f'/CN={name}')
            _openssl(directory, 'x509', '-req', '-in', f'{name}.csr', '-CA', 'ca.pem', '-CAkey',
                     'ca.key', '-CAcreateserial', '-days', '2', '-out', f'{name}.pem',
                     '-extfile', f'{name}.ext')
            self.sites[name] = Site(str(directory / f'{name}.pem'),
                                    str(directory / f'{name}.key'))
            _openssl(directory, 'req', '-x509', *CURVE, '-keyout', f'{name}.stranger.key',
                     '-out', f'{name}.stranger.pem', '-days', '2', '-subj', f'/CN={name}',
                     '-addext', f'subjectAltName={alternative}')
            self.strangers[name] = Site(str(directory / f'{name}.stranger.pem'),
                                        str(directory / f'{name}.stranger.key'))

    def __getitem__(self, name):
        """Return site `name`'s Site."""
        return self.sites[name]

    def __exit__(self, *exc):
        """Delete the files."""
        self._directory.cleanup()
        return False


def link_parameters(sites, side, peer, listen='', connect='', pair='kraft_master/test'):
    """Return the (name, value) parameters of kraft_master_zenoh_link for `side` of `sites`."""
    own = sites[side]
    # Only the endpoint given: rcl refuses `-p connect:=` (an empty value).
    ends = [('listen', listen)] if listen else [('connect', connect)]
    return [('side', side), ('pair', pair), *ends, ('tls.root_ca', sites.ca),
            ('tls.certificate', own.certificate), ('tls.private_key', own.private_key),
            ('tls.peer_common_name', peer)]
