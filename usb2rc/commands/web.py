"""`usb2rc web [--listen 127.0.0.1:8080] [--socket PATH] [--token-file F]`: the status page.

A separate process from the daemon: it reads the daemon's read-only status socket (where
`usb2rc run` puts it by default, unless --socket says otherwise) and serves a page (the
daemon's state; one card per node; the devices; one card per output: its port, open or not
and why, whether it sends failsafe, its link; the service events; the `check` verdict of the
running config), `GET /api/status` (the `run --stats-format json` record plus the node
snapshot) and a live stream to the page. It has no control actions.

It listens on localhost unless told otherwise. Any other address needs `--token-file`: the
page shows your sticks and links to whoever can reach it, so a token keeps it to those you
give the link to (docs/PI.md, "Phone access at the field"; the traffic is plain HTTP).
"""

from __future__ import annotations

import argparse
import errno
import ipaddress
import logging
import socket
import sys

from usb2rc import status_socket

log = logging.getLogger("usb2rc.web")

DEFAULT_LISTEN = "127.0.0.1:8080"
MIN_TOKEN_CHARS = 16


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "web",
        help="serve a status page of the running daemon (read-only; localhost by default)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--listen",
        default=DEFAULT_LISTEN,
        metavar="HOST:PORT",
        help=f"address to serve on (default {DEFAULT_LISTEN}); a non-loopback one needs "
        "--token-file",
    )
    parser.add_argument(
        "--socket",
        metavar="PATH",
        help="the daemon's status socket (default: where `usb2rc run` puts it, run by this "
        "user: $RUNTIME_DIRECTORY/status.sock, else $XDG_RUNTIME_DIR/usb2rc/status.sock, "
        f"else {status_socket.SERVICE_SOCKET} for root and /tmp/usb2rc-UID/status.sock "
        "for another user; `usb2rc run` logs where its socket is)",
    )
    parser.add_argument(
        "--token-file",
        metavar="F",
        help=f"a file holding the token (at least {MIN_TOKEN_CHARS} characters) every "
        "request must carry: open the page as http://HOST:PORT/?token=...",
    )
    parser.add_argument(
        "--log-level", default="info", choices=["debug", "info", "warning", "error"]
    )
    parser.set_defaults(func=run)


class UsageError(ValueError):
    """A wrong option: exit 2 with the message (it says the fix)."""


def parse_listen(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 < int(port) < 65536:
        raise UsageError(f"--listen {text}: give HOST:PORT, such as {DEFAULT_LISTEN}")
    return host.strip("[]") or "0.0.0.0", int(port)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: it may resolve to anything


def read_token(path: str | None, host: str) -> str | None:
    """The token from --token-file; refused: a non-loopback address without one."""
    if path is None:
        if not is_loopback(host):
            raise UsageError(
                f"--listen {host}: other machines could see the page without a token: give "
                "--token-file F as well (a file with a long random token, for example "
                "`openssl rand -hex 16 > F`), or listen on 127.0.0.1 and use an SSH tunnel "
                '(docs/PI.md, "Phone access at the field")'
            )
        return None
    try:
        with open(path, encoding="utf-8") as file:
            token = file.read().strip()
    except OSError as exc:
        raise UsageError(f"--token-file {path}: {exc.strerror}") from exc
    if len(token) < MIN_TOKEN_CHARS or any(c.isspace() for c in token):
        raise UsageError(
            f"--token-file {path}: the token must be one word of at least {MIN_TOKEN_CHARS} "
            "characters (`openssl rand -hex 16 > F` makes one)"
        )
    return token


def listen_problem(listen: str, exc: OSError) -> str:
    """Why `--listen` cannot be served, and the fix (a usage error: exit 2)."""
    if exc.errno == errno.EADDRINUSE:
        why = "the address is already in use (another `usb2rc web`, or another server)"
    elif exc.errno == errno.EACCES:
        why = "ports below 1024 need root"
    elif exc.errno == errno.EADDRNOTAVAIL:
        why = "this machine has no such address"
    elif isinstance(exc, socket.gaierror):
        why = f"unknown host ({exc.strerror})"
    else:
        why = exc.strerror or str(exc)
    return (
        f"cannot listen on {listen}: {why}: give another address with --listen HOST:PORT, "
        f"such as --listen 127.0.0.1:8081"
    )


def run(args: argparse.Namespace) -> int:
    try:
        host, port = parse_listen(args.listen)
        token = read_token(args.token_file, host)
    except UsageError as exc:
        print(f"usb2rc web: {exc}", file=sys.stderr)
        return 2
    logging.basicConfig(
        level=getattr(logging, args.log_level.upper()), format="%(levelname)s %(message)s"
    )
    path = args.socket or status_socket.default_path()
    # Here, not at the top: `usb2rc --help` imports every command's module (cli.build_parser),
    # and only this one needs starlette and uvicorn (~0.1 s to import).
    from usb2rc.web.feed import StatusFeed
    from usb2rc.web.server import listen, serve

    try:
        sockets = listen(host, port)
    except OSError as exc:
        print(f"usb2rc web: {listen_problem(args.listen, exc)}", file=sys.stderr)
        return 2
    whence = "--socket" if args.socket else "the default of `usb2rc run` for this user"
    log.info(
        "usb2rc web: http://%s:%d/, reading the status socket %s (%s)", host, port, path, whence
    )
    started = serve(StatusFeed(path, default=not args.socket), token, sockets)
    return 0 if started else 1
