"""`usb2rc install-system [--root DIR] [--config FILE] [--web] [--force] [--print NAME]`.

The package carries the systemd unit, the udev rule, the sysusers file, the unit's notes and
the starter configs (`usb2rc/data/system/`, `usb2rc/data/config/`), so `pip install usb2rc`
needs no clone. This writes them where a Pi (or any systemd host) wants them, creates the
service user with systemd-sysusers, and never overwrites an existing /etc/usb2rc/usb2rc.yaml
(a symlink to nothing there is refused, naming the link and its target). An installed file
that differs from what this usb2rc would write (edited by hand, or by an older usb2rc) is
kept, with a unified diff of what would change; `--force` replaces it.

The config that ends up at /etc/usb2rc/usb2rc.yaml (the kept one, or the one installed) is
read: when its outputs open IP sockets (`udpout:`, `udpin:`, `socket://`, `rfc2217://`),
which the unit forbids, the drop-in usb2rc.service.d/network.conf allows IP to the hosts they
name (`usb2rc/service/sandbox.py` says how). With `--root DIR` everything goes under DIR (a
scratch root, an image being built); with `--print NAME` one file is printed as it would be
installed instead (network.conf: for --config FILE, default the starter default.yaml).

The unit's ExecStart= names the usb2rc that runs this command: the entry-point script it was
started as, else the `usb2rc` beside the running Python (a venv's bin/), else that Python
with `-m usb2rc`. So the service runs the venv the command came from.

`--web` installs usb2rc-web.service as well: `usb2rc web`, the read-only status page, on
127.0.0.1:8080 (docs/PI.md, "Phone access at the field").
"""

from __future__ import annotations

import argparse
import difflib
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from usb2rc.runtime.textfile import DanglingLink, resolved_target
from usb2rc.service import sandbox as service_sandbox

# The shipped unit's ExecStart= program: what an install into /opt/usb2rc/venv gives.
TEMPLATE_PROGRAM = "/opt/usb2rc/venv/bin/usb2rc"
CONFIG_TARGET = "/etc/usb2rc/usb2rc.yaml"
SERVICE_GROUP = "usb2rc"
# ProtectHome=yes hides these from the service: a usb2rc installed under them cannot start.
HIDDEN_FROM_SERVICE = ("/home/", "/root/", "/run/user/")


@dataclass(frozen=True)
class SystemFile:
    name: str  # --print NAME; the file's name in the package
    package_dir: str  # under usb2rc/data/
    target: str  # absolute path on the installed system
    mode: int
    keep_existing: bool = False  # the user's config: never overwritten
    generated: bool = False  # written from the config, not a packaged file


FILES = (
    SystemFile("usb2rc.sysusers", "system", "/usr/lib/sysusers.d/usb2rc.conf", 0o644),
    SystemFile("70-usb2rc.rules", "system", "/etc/udev/rules.d/70-usb2rc.rules", 0o644),
    SystemFile("usb2rc.service", "system", "/etc/systemd/system/usb2rc.service", 0o644),
    SystemFile("SERVICE.md", "system", "/usr/share/doc/usb2rc/SERVICE.md", 0o644),
    SystemFile("default.yaml", "config", CONFIG_TARGET, 0o640, keep_existing=True),
)
EXAMPLES = tuple(
    SystemFile(name, "config", CONFIG_TARGET, 0o640, keep_existing=True)
    for name in ("hotas.yaml", "mavlink.yaml")
)
WEB_UNIT = SystemFile(
    "usb2rc-web.service", "system", "/etc/systemd/system/usb2rc-web.service", 0o644
)
UNITS = ("usb2rc.service", WEB_UNIT.name)  # ExecStart= names the usb2rc that installs them
# Written after the config, from it (service_sandbox): only when it opens IP sockets.
DROP_IN = SystemFile("network.conf", "", service_sandbox.DROP_IN, 0o644, generated=True)
BY_NAME = {f.name: f for f in (*FILES, *EXAMPLES, DROP_IN, WEB_UNIT)}

# What is left after the files are in place, in order; the config's port comes first when
# an output has none (the unit runs `usb2rc run --config`, without --port).
SET_PORT_STEP = (
    "set the serial port in {config}: `port:` under `outputs:` (e.g. `port: /dev/serial0`; "
    "{missing} has none, and the service gives no --port)"
)
CHECK_STEP = "{sudo}{program} check --config {config}"
SYSTEM_STEPS = (
    "sudo udevadm control --reload"
    " && sudo udevadm trigger --subsystem-match=hidraw --subsystem-match=usb",
    "sudo systemctl daemon-reload && sudo systemctl enable --now usb2rc",
)
WEB_NEXT_STEP = "sudo systemctl enable --now usb2rc-web  # then http://127.0.0.1:8080/"


def add_parser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "install-system",
        help="install the systemd unit, udev rule, service user and config (or print them)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--root", metavar="DIR", default="/", help="install under DIR instead of / (default: /)"
    )
    parser.add_argument(
        "--config",
        metavar="FILE",
        help=f"install FILE as {CONFIG_TARGET} (default: the starter default.yaml); "
        "it must pass `usb2rc check`, and an existing one is still kept",
    )
    parser.add_argument(
        "--web",
        action="store_true",
        help="also install usb2rc-web.service: the read-only status page on 127.0.0.1:8080",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace installed files that differ from this usb2rc's (the config is still kept)",
    )
    parser.add_argument(
        "--exec",
        dest="program",
        metavar="PATH",
        help="the usb2rc the unit's ExecStart= runs (default: the one running this command)",
    )
    parser.add_argument(
        "--print",
        dest="print_name",
        metavar="NAME",
        choices=sorted(BY_NAME),
        help="print one file as it would be installed: " + ", ".join(sorted(BY_NAME)),
    )
    parser.set_defaults(func=run)


# --------------------------------------------------------------------------- contents


def packaged_text(file: SystemFile) -> str:
    return (resources.files("usb2rc") / "data" / file.package_dir / file.name).read_text()


def running_program() -> list[str]:
    """The command that runs this usb2rc again, as absolute paths (see the module doc)."""
    started_as = os.path.abspath(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    if os.path.basename(started_as) == "usb2rc" and os.access(started_as, os.X_OK):
        return [started_as]
    beside_python = Path(os.path.abspath(sys.executable)).parent / "usb2rc"
    if os.access(beside_python, os.X_OK):
        return [str(beside_python)]
    return [os.path.abspath(sys.executable), "-m", "usb2rc"]


def systemd_quote(word: str) -> str:
    """A word for a systemd command line: quoted when it holds blanks, quotes or `\\`."""
    if re.search(r"[\s\"'\\]", word):
        return '"' + word.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return word


def unit_text(template: str, program: list[str]) -> str:
    """The shipped unit with ExecStart= running `program` instead of /opt/usb2rc/venv's."""
    head = " ".join(systemd_quote(word) for word in program)
    text, count = re.subn(
        rf"^ExecStart={re.escape(TEMPLATE_PROGRAM)} ",
        lambda _match: f"ExecStart={head} ",
        template,
        flags=re.MULTILINE,
    )
    if count != 1:
        raise RuntimeError(f"the packaged unit has no ExecStart={TEMPLATE_PROGRAM} line")
    return text


def rendered(file: SystemFile, program: list[str]) -> str:
    text = packaged_text(file)
    return unit_text(text, program) if file.name in UNITS else text


def drop_in_for(config_text: str, source: str, root: Path) -> tuple[str | None, list[str]]:
    """network.conf for the config (None: it opens no IP socket) and the warnings to show."""
    from usb2rc.configfile import load_config_text

    peers = service_sandbox.network_peers(load_config_text(config_text, source), root)
    warnings = [p.warning for p in peers if p.warning]
    if not peers:
        return None, warnings
    return service_sandbox.drop_in_text(peers, CONFIG_TARGET), warnings


# --------------------------------------------------------------------------- writing


def under_root(root: Path, target: str) -> Path:
    return root / target.lstrip("/")


def make_dirs(directory: Path) -> None:
    """Missing directories 0755 whatever the umask (sudo's may be 077): the service user
    must get through /etc/usb2rc to its config."""
    if directory.is_dir():
        return
    make_dirs(directory.parent)
    directory.mkdir()
    os.chmod(directory, 0o755)


def write_file(path: Path, text: str, mode: int) -> str:
    """Atomically (temp file + rename); 'wrote' or 'unchanged'."""
    if same_file(path, text, mode):
        return "unchanged"
    make_dirs(path.parent)
    fd, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w") as stream:
            stream.write(text)
        os.chmod(temp, mode)
        os.replace(temp, path)
    except BaseException:
        os.unlink(temp)
        raise
    return "wrote"


def same_file(path: Path, text: str, mode: int) -> bool:
    if path.is_symlink() or not path.is_file():
        return False
    return path.read_text() == text and (path.stat().st_mode & 0o777) == mode


def edited_by_hand(path: Path, text: str) -> str | None:
    """What differs between the installed file and text (a unified diff, or what the link
    points to), or None when there is nothing to keep (absent, or the same text)."""
    if path.is_symlink():
        return f"{path} is a symlink to {os.readlink(path)}\n"
    if not path.exists():
        return None
    try:
        installed = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        return f"{path}: cannot read ({exc}): not the file usb2rc installs\n"
    if installed == text:
        return None
    lines = difflib.unified_diff(
        installed.splitlines(keepends=True),
        text.splitlines(keepends=True),
        fromfile=f"{path} (installed)",
        tofile=f"{path} (this usb2rc's)",
    )
    return "".join(line if line.endswith("\n") else line + "\n" for line in lines)


def place(path: Path, text: str, file: SystemFile, force: bool) -> str | None:
    """Write one service file (printing what happened); a problem, or None. A file that
    differs from text is kept, its diff shown, unless force."""
    difference = None if force else edited_by_hand(path, text)
    if difference is not None:
        print(f"{'kept':<10} {path} (differs from {file.name}: diff on stderr)")
        sys.stderr.write(difference)
        return (
            f"{path} differs from this usb2rc's {file.name} and was kept: `--force` replaces "
            "it (settings of your own belong in a drop-in: `systemctl edit usb2rc`)"
        )
    print(f"{write_file(path, text, file.mode):<10} {path} (from {file.name})")
    return None


def group_id(root: Path, name: str) -> int | None:
    """The group's id in ROOT/etc/group (what systemd-sysusers wrote), or None."""
    try:
        lines = under_root(root, "/etc/group").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        fields = line.split(":")
        if len(fields) >= 3 and fields[0] == name and fields[2].isdigit():
            return int(fields[2])
    return None


def create_service_user(root: Path, sysusers_text: str) -> str | None:
    """systemd-sysusers for the usb2rc user and group; None, or what went wrong."""
    program = shutil.which("systemd-sysusers")
    if program is None:
        return "systemd-sysusers not found: create the user with `sudo useradd --system usb2rc`"
    make_dirs(under_root(root, "/etc"))  # where it writes passwd and group
    result = subprocess.run(
        [program, f"--root={root}", "-"],
        input=sysusers_text,
        capture_output=True,
        text=True,
        check=False,
    )
    if result.returncode != 0:
        return f"systemd-sysusers failed: {result.stderr.strip() or result.returncode}"
    return None


def give_config_to_group(root: Path, path: Path) -> str:
    """root:usb2rc 0640, so the service (group usb2rc) reads it and other users do not."""
    gid = group_id(root, SERVICE_GROUP)
    if gid is None:
        return f"no group {SERVICE_GROUP} yet: `sudo chgrp {SERVICE_GROUP} {path}` once it exists"
    if os.geteuid() != 0:
        return f"not root: `sudo chown root:{SERVICE_GROUP} {path}`"
    os.chown(path, 0, gid)
    return ""


def checked_config(path: str) -> str:
    """The text of a config that passes `usb2rc check`; raises ConfigError / OSError."""
    from usb2rc.configfile import load_config

    load_config(path)
    return Path(path).read_text()


# --------------------------------------------------------------------------- command


def run(args: argparse.Namespace) -> int:
    program = [args.program] if args.program else running_program()
    if args.print_name:
        return print_file(BY_NAME[args.print_name], program, args.config)
    usage = _usage_problem(args.root, program)
    if usage is not None:
        print(f"usb2rc install-system: {usage}", file=sys.stderr)
        return 2
    config_text = _config_text(args.config)
    if config_text is None:
        return 2
    root = Path(args.root)
    config_name = args.config or BY_NAME["default.yaml"].name
    request = Request(root, program, config_text, config_name, args.force, args.web)
    try:
        problems = install(request)
    except OSError as exc:
        hint = " (run it with sudo)" if isinstance(exc, PermissionError) else ""
        print(f"usb2rc install-system: {exc}{hint}", file=sys.stderr)
        return 1
    _print_advice(root, program, problems, args.web)
    return 1 if problems else 0


def print_file(file: SystemFile, program: list[str], config: str | None) -> int:
    """--print NAME: the file as installed; network.conf for --config (or default.yaml)."""
    if not file.generated:
        sys.stdout.write(rendered(file, program))
        return 0
    config_text = _config_text(config)
    if config_text is None:
        return 2
    text, warnings = drop_in_for(config_text, config or "default.yaml", Path("/"))
    for warning in warnings:
        print(f"usb2rc install-system: warning: {warning}", file=sys.stderr)
    sys.stdout.write(text or service_sandbox.drop_in_text([], config or "default.yaml"))
    return 0


def _usage_problem(root: str, program: list[str]) -> str | None:
    if sys.platform != "linux" and root == "/":
        return "systemd and udev are Linux; --print shows the files, --root DIR writes them"
    if not os.path.isabs(program[0]):
        return f"--exec needs an absolute path (systemd runs it): {program[0]}"
    return None


def _config_text(path: str | None) -> str | None:
    if path is None:
        return packaged_text(BY_NAME["default.yaml"])
    from usb2rc.configfile import ConfigError

    try:
        return checked_config(path)
    except ConfigError as exc:
        print("\n".join(exc.errors), file=sys.stderr)
    except OSError as exc:
        print(f"{path}: cannot read: {exc.strerror or exc}", file=sys.stderr)
    print(f"usb2rc install-system: not installing {path}", file=sys.stderr)
    return None


@dataclass(frozen=True)
class Request:
    """What to install: the command line, resolved."""

    root: Path
    program: list[str]
    config_text: str
    config_name: str  # --config FILE as given, or the starter's name
    force: bool = False
    web: bool = False  # usb2rc-web.service too


def install(request: Request) -> list[str]:
    """Write every file under root (printing one line each); the problems left to fix."""
    problems: list[str] = []
    for file in FILES:
        if file.keep_existing:
            problems += install_config(request, file)
            continue
        text = rendered(file, request.program)
        path = under_root(request.root, file.target)
        problem = place(path, text, file, request.force)
        problems += [problem] if problem else []
        if file.name == "usb2rc.sysusers" and problem is None:
            problem = create_service_user(request.root, text)
            problems += [problem] if problem else []
    if request.web:
        path = under_root(request.root, WEB_UNIT.target)
        problem = place(path, rendered(WEB_UNIT, request.program), WEB_UNIT, request.force)
        problems += [problem] if problem else []
    return problems + install_drop_in(request)


def install_config(request: Request, file: SystemFile) -> list[str]:
    """The config, only where there is none; a dangling symlink is refused (see textfile)."""
    path = under_root(request.root, file.target)
    try:
        resolved_target(path)
    except DanglingLink as exc:
        print(f"{'refused':<10} {path} (a symlink to nothing)")
        return [str(exc)]
    if path.exists():
        print(f"kept       {path} (exists: not overwritten)")
        return []
    verb = write_file(path, request.config_text, file.mode)
    print(f"{verb:<10} {path} (from {request.config_name})")
    problem = give_config_to_group(request.root, path)
    return [problem] if problem else []


def installed_config(request: Request) -> tuple[str, str] | None:
    """The text and name of the config at /etc/usb2rc/usb2rc.yaml now, None if none."""
    path = under_root(request.root, CONFIG_TARGET)
    try:
        return path.read_text(), str(path)
    except OSError:
        return None


def install_drop_in(request: Request) -> list[str]:
    """network.conf for the installed config's IP outputs (service_sandbox)."""
    from usb2rc.configfile import ConfigError

    config = installed_config(request)
    if config is None:
        return []
    path = under_root(request.root, DROP_IN.target)
    try:
        text, warnings = drop_in_for(*config, request.root)
    except ConfigError as exc:
        return [
            f"{config[1]} does not pass `usb2rc check` ({len(exc.errors)} error(s)): "
            f"no {DROP_IN.name} written for its network outputs"
        ]
    for warning in warnings:
        print(f"usb2rc install-system: warning: {warning}", file=sys.stderr)
    if text is None:
        if path.exists():
            print(f"kept       {path} (the config opens no IP socket: remove it if unused)")
        return []
    problem = place(path, text, DROP_IN, request.force)
    return [problem] if problem else []


def _print_advice(root: Path, program: list[str], problems: list[str], web: bool = False) -> None:
    if program[0].startswith(HIDDEN_FROM_SERVICE):
        print(
            f"warning: ExecStart={shlex.join(program)} is under a home directory, which the "
            "unit hides (ProtectHome=yes): the service cannot start it. Install usb2rc in a "
            "venv under /opt (docs/PI.md) and run its `usb2rc install-system`.",
            file=sys.stderr,
        )
    for problem in problems:
        print(f"usb2rc install-system: {problem}", file=sys.stderr)
    print("\n".join(next_steps(root, program, web)))


def next_steps(root: Path, program: list[str], web: bool = False) -> list[str]:
    """What is left to do, one command or task a line: the port (when the installed config
    has an output without one), `check`, then the udev rule and the service. Under
    `--root DIR` the config is named where it is now; the system's commands come after."""
    config = under_root(root, CONFIG_TARGET)
    missing = outputs_without_port(config)
    lines = ["next:"]
    if missing:
        lines.append("  " + SET_PORT_STEP.format(config=config, missing=", ".join(missing)))
    sudo = "sudo " if root == Path("/") else ""
    lines.append("  " + CHECK_STEP.format(sudo=sudo, program=shlex.join(program), config=config))
    if root != Path("/"):
        lines.append(f"then, on the system that runs from {root}:")
    lines += [f"  {step}" for step in SYSTEM_STEPS]
    if web:
        lines.append(f"  {WEB_NEXT_STEP}")
    return lines


def outputs_without_port(path: Path) -> list[str]:
    """`outputs[0]`, ... of the config at path that have no `port:` (the service passes no
    --port); none when it cannot be read or does not pass `check` (its step says why)."""
    from usb2rc.configfile import ConfigError, load_config

    try:
        config = load_config(str(path))
    except (ConfigError, OSError, UnicodeDecodeError):
        return []
    return [f"outputs[{i}]" for i, output in enumerate(config.outputs) if not output.port]
