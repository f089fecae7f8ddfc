"""Write a daemon configuration for one camera from the annotated template, ready for the unit.

  edgedsm init line3                                   writes /etc/edgedsm/line3.toml
  edgedsm init line3 --camera aravis:Basler-acA2440-20gm-23456789
  edgedsm init line3 --dir ./etc --force               another directory; replace an old file

The template is the annotated example shipped with edgedsm (config/daemon/example.toml):
[device] name becomes NAME (the MQTT topics are edgedsm/NAME/...), [camera] uri the --camera
given; the template's instance name line3 becomes NAME everywhere (MQTT user too).
The file is validated before it is put in place, written with mode 0640 and, where the
group exists, group 'edgedsm' (the group the service reads its configuration with; see
systemd/README.md). An existing file is never replaced without --force. Then edit the relay,
regions and broker, check the file, and enable the service instance NAME:

  edgedsm check-config /etc/edgedsm/line3.toml && systemctl enable --now edgedsm@line3

Exit status: 0 written, 78 bad NAME or camera URI, a file already there, or a template that
does not validate.
"""

from __future__ import annotations

import argparse
import contextlib
import grp
import os
import re
import tomllib
from pathlib import Path

from edgedsm.errors import ConfigError
from edgedsm.resources import data_file

NAME = "init"
HELP = "write /etc/edgedsm/NAME.toml from the annotated template and say how to enable the unit"

TEMPLATE = "config/daemon/example.toml"
TEMPLATE_INSTANCE = "line3"  # the instance name the template is written for
UNIT = "systemd/edgedsm@.service"
CONFIG_GROUP = "edgedsm"
FILE_MODE = 0o640
# an instance name is a file name, a systemd instance and the MQTT device name all at once
INSTANCE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", metavar="NAME",
                        help="instance name, e.g. line3: unit edgedsm@line3, topics edgedsm/line3/...")
    parser.add_argument("--dir", type=Path, default=Path("/etc/edgedsm"),
                        help="where to write NAME.toml (default /etc/edgedsm, where the unit looks)")
    parser.add_argument("--camera", metavar="URI", help="camera URI (default: the template's, to be edited)")
    parser.add_argument("--force", action="store_true", help="replace an existing NAME.toml")


def toml_string(value: str) -> str:
    """A TOML basic string holding ``value`` (control characters are refused by the URI check)."""
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'


def render(template: str, name: str, camera: str | None) -> str:
    """The template with its instance name (line3) replaced by ``name`` everywhere (device name,
    MQTT user, comments) and, if given, [camera] uri replaced; comments are kept."""
    text = re.sub(rf"\b{TEMPLATE_INSTANCE}\b", lambda _: name, template)
    if camera is not None:
        lines, table, done = [], "", False
        for line in text.splitlines(keepends=True):
            header = re.match(r"\s*\[([A-Za-z_.]+)\]", line)
            table = header.group(1) if header else table
            match = None if header or done or table != "camera" else re.match(r'uri\s*=\s*"[^"]*"', line)
            if match:
                line, done = f"uri = {toml_string(camera)}" + line[match.end():], True
            lines.append(line)
        text = "".join(lines)
    data = tomllib.loads(text)
    if data.get("device", {}).get("name") != name or (
            camera is not None and data.get("camera", {}).get("uri") != camera):
        raise ConfigError(f"the template {TEMPLATE} has no [device] name / [camera] uri line to fill in")
    return text


def run(args: argparse.Namespace) -> int:
    from edgedsm.config import load_config

    if not INSTANCE.fullmatch(args.name):
        raise ConfigError(f"NAME {args.name!r}: use 1 to 64 letters, digits, '_', '.', '-', starting "
                          f"with a letter or digit (it names the file, the unit instance and the topics)")
    if args.camera is not None:
        from edgedsm.devices.camera.uri import parse_camera_uri

        parse_camera_uri(args.camera)  # a typo is refused here with the URI's own message
    target = args.dir / f"{args.name}.toml"
    if target.exists() and not args.force:
        raise ConfigError(f"{target} exists already: edit it, or give --force to replace it")
    text = render(data_file(TEMPLATE).read_text(encoding="utf-8"), args.name, args.camera)
    args.dir.mkdir(parents=True, exist_ok=True)
    staging = args.dir / f".{args.name}.toml.edgedsm-init"
    _write_private(staging, text)
    try:
        try:
            load_config(staging)
        except ConfigError as exc:
            raise ConfigError(str(exc).replace(str(staging), str(target))) from None
        if args.force:
            os.replace(staging, target)
        else:
            try:
                os.link(staging, target)  # fails if the file appeared meanwhile: never overwrite
            except FileExistsError:
                raise ConfigError(f"{target} exists already: edit it, or give --force to replace it") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            staging.unlink()
    group_note = _give_to_group(target)
    print(f"wrote {target} (mode {FILE_MODE:04o}{group_note})")
    _print_next_steps(args.name, target)
    return 0


def _write_private(path: Path, text: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        path.unlink()  # a staging file left by an interrupted run
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, FILE_MODE)
    with os.fdopen(fd, "w", encoding="utf-8") as handle:
        os.fchmod(handle.fileno(), FILE_MODE)  # whatever the umask
        handle.write(text)


def _give_to_group(path: Path) -> str:
    """Hand the file to group 'edgedsm' (the unit's SupplementaryGroups=) where possible."""
    try:
        gid = grp.getgrnam(CONFIG_GROUP).gr_gid
    except KeyError:
        return (f"; NOTE: group '{CONFIG_GROUP}' does not exist, so the service cannot read the file: "
                f"create it (systemd/README.md) and run chgrp {CONFIG_GROUP} {path}")
    try:
        os.chown(path, -1, gid)
    except PermissionError:
        return f"; NOTE: could not give it to group '{CONFIG_GROUP}': run chgrp {CONFIG_GROUP} {path} as root"
    return f", group {CONFIG_GROUP}"


def _print_next_steps(name: str, target: Path) -> None:
    unit = data_file(UNIT)
    print(f"""
next steps:
  1. edit {target}: camera, [laser] relay, [[regions]], [mqtt] broker
  2. check it:        edgedsm check-config {target}
  3. MQTT password:   install -m 600 /dev/null /etc/edgedsm/credentials/{name}.mqtt-password
                      (then write the password into it; never into the TOML file)
  4. the unit, once:  cp {unit} /etc/systemd/system/ && systemctl daemon-reload
                      (its ExecStart= expects edgedsm in /opt/edgedsm/.venv/bin; see systemd/README.md)
  5. enable it:       systemctl enable --now edgedsm@{name}
     and watch it:    journalctl -u edgedsm@{name} -f""")
