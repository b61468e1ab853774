"""``lunad keys``: make and list the CURVE key pairs of a daemon and its clients."""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from pathlib import Path
from typing import Any

DESCRIPTION = """\
Make the ZeroMQ CURVE keys that encrypt a TCP endpoint and admit only known
clients (docs/security.md), or list the public keys in a directory.

  server DIR         DIR/server.key (public) and DIR/server.key_secret (mode 0600):
                     the daemon's pair ([publish] curve_secret_key is the secret file;
                     every client gets server.key)
  client NAME DIR    DIR/NAME.key and DIR/NAME.key_secret (mode 0600): a client's
                     pair; NAME.key goes into the daemon's curve_clients directory,
                     NAME.key_secret stays with the robot code
  list DIR           each *.key file in DIR: its name and public key (Z85)

The files are ZPL certificates, as zmq.auth.create_certificates writes them. Existing
files are never replaced unless --force is given. Exit codes: 0 done; 1 refused (a file
exists, a file or directory cannot be written or read), with one line saying why;
2 bad arguments.
"""

EPILOG = """\
examples:
  sudo lunad keys server /etc/lunad/curve
  sudo chown lunad: /etc/lunad/curve/server.key_secret   # the daemon reads it
  lunad keys client robot1 ~/curve                         # on the robot's machine
  sudo cp ~/curve/robot1.key /etc/lunad/curve/clients/     # on the daemon's machine
  lunad keys list /etc/lunad/curve/clients
  lunad keys server /etc/lunad/curve --force               # a new server pair
"""

NAME_RE = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}")
"""A client's name: its files are NAME.key and NAME.key_secret, so no path separator,
and no leading dot (hidden, and the temporary files' prefix)."""
PUBLIC_MODE = 0o644
SECRET_MODE = 0o600
DIR_MODE = 0o755  # a new DIR: the public keys are for others to read


def add_parser(sub: Any) -> None:
    """Register ``keys``."""
    p = sub.add_parser(
        "keys",
        help="make and list CURVE keys for encrypted TCP endpoints",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = p.add_subparsers(
        title="actions", metavar="ACTION", dest="action", required=True, parser_class=type(p)
    )
    server = actions.add_parser("server", help="make the daemon's key pair in DIR")
    server.add_argument("dir", metavar="DIR", help="directory for server.key and server.key_secret")
    server.add_argument("--force", action="store_true", help="replace existing files")
    client = actions.add_parser("client", help="make a client's key pair in DIR")
    client.add_argument("name", metavar="NAME", help="the client's name: NAME.key, NAME.key_secret")
    client.add_argument("dir", metavar="DIR", help="directory for the two files")
    client.add_argument("--force", action="store_true", help="replace existing files")
    listing = actions.add_parser("list", help="list the public keys (*.key) in DIR")
    listing.add_argument("dir", metavar="DIR", help="directory of key files")
    for each in (server, client, listing):
        each.set_defaults(func=run, _parser=each)
    p.set_defaults(func=run)


class KeysError(Exception):
    """Why ``lunad keys`` did nothing (or undid what it did): one line for the user."""


def run(args: argparse.Namespace) -> int:
    """Make or list keys; 0 when done, 1 with one line on stderr when refused."""
    try:
        if args.action == "list":
            return _list(Path(args.dir))
        name = "server" if args.action == "server" else args.name
        if args.action == "client" and not NAME_RE.fullmatch(name):
            args._parser.error(
                f"NAME must be 1..64 letters, digits, '_', '-' or '.', not starting with "
                f"'.': got {name!r}"
            )
        public, secret, key = make_pair(Path(args.dir), name, args.force)
    except KeysError as exc:
        print(f"lunad keys: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {public} (public) and {secret} (secret, mode 0600)")
    print(f"public key: {key}")
    if args.action == "server":
        print(f"give {public} to every client (Subscriber curve_server_key); in [publish],")
        print(f'curve_secret_key = "{os.path.abspath(secret)}", readable by the daemon alone')
    else:
        print(f"copy {public} into the daemon's curve_clients directory; {secret}")
        print("stays with the robot code (Subscriber curve_client_key)")
    return 0


def make_pair(directory: Path, name: str, force: bool = False) -> tuple[Path, Path, str]:
    """Write ``directory/name.key`` (mode 0644) and ``directory/name.key_secret`` (mode
    0600), creating ``directory`` if needed; returns both paths and the public key (Z85).

    The pair is made by ``zmq.auth.create_certificates`` in a private temporary
    directory inside ``directory`` (mode 0700, so the secret is never readable by
    others, whatever the umask), given its modes there, then moved into place: without
    ``force`` by a hard link, which fails if the name exists, so nothing is replaced
    even by a file created meanwhile; with it by a rename. A failure leaves neither
    file of a new pair behind.

    Raises:
        KeysError: ``directory`` is not one, a file exists (without ``force``), or the
            directory or files cannot be written.
    """
    from zmq.auth import create_certificates

    if os.path.lexists(directory) and not directory.is_dir():
        raise KeysError(f"{directory}: not a directory: give the folder the key pair goes in")
    public = directory / f"{name}.key"
    secret = directory / f"{name}.key_secret"
    if not force:
        existing = [str(p) for p in (public, secret) if os.path.lexists(p)]
        if existing:
            verb = "exists" if len(existing) == 1 else "exist"
            raise KeysError(f"{' and '.join(existing)} {verb}; --force replaces them")
    try:
        directory.mkdir(mode=DIR_MODE, parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=directory, prefix=".lunad-keys-") as tmp:
            made_public, made_secret = (Path(p) for p in create_certificates(tmp, name))
            os.chmod(made_public, PUBLIC_MODE)
            os.chmod(made_secret, SECRET_MODE)
            key = _public_key(made_public)
            if force:
                os.replace(made_secret, secret)
                os.replace(made_public, public)
            else:
                _link_new(made_secret, secret)
                try:
                    _link_new(made_public, public)
                except BaseException:
                    secret.unlink(missing_ok=True)
                    raise
    except KeysError:
        raise
    except OSError as exc:
        where = exc.filename or directory
        raise KeysError(f"cannot write {where}: {exc.strerror or exc}") from None
    return public, secret, key


def _link_new(src: Path, dst: Path) -> None:
    """Give ``src`` the name ``dst``, which must not exist yet.

    Raises:
        KeysError: ``dst`` exists (it appeared after the first check).
    """
    try:
        os.link(src, dst)
    except FileExistsError:
        raise KeysError(f"{dst} exists; --force replaces it") from None


def _public_key(path: Path) -> str:
    """The Z85 public key of the key file ``path``, checked as the daemon checks it."""
    from lunad.protocol.curve_keys import read_key_file

    try:
        return read_key_file(path)[0].decode("ascii")
    except ValueError as exc:
        raise KeysError(str(exc)) from None


def _list(directory: Path) -> int:
    """Print each ``*.key`` in ``directory`` as the daemon reads it: name, public key;
    files it would skip are named on stderr with the reason."""
    from lunad.daemon.config import key_dir_problem
    from lunad.protocol.curve_keys import read_key_file

    problem = key_dir_problem(directory)
    if problem is not None:
        raise KeysError(problem)
    files = sorted(p for p in directory.iterdir() if p.name.endswith(".key"))
    for path in files:
        try:
            public, _ = read_key_file(path)
        except ValueError as exc:
            print(f"lunad keys: skipped (the daemon would too): {exc}", file=sys.stderr)
            continue
        print(f"{path.name.removesuffix('.key'):<24} {public.decode('ascii')}")
    if not files:
        print(f"lunad keys: no *.key file in {directory}", file=sys.stderr)
    return 0
