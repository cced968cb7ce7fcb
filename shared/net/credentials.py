"""This installation's own credentials: generated on first use, readable by its user only.

A network config may name `"@local"` for the haptic server's `users_file` and the sim's
`password_file` (the shipped default, `configs/network/loopback.toml`, does): both then
resolve to files in the user's config directory (`$XDG_CONFIG_HOME/haptic-local-model/
credentials/`, or `$HAPTIC_CREDENTIALS_DIR`), made on first use with a random password for
user `sim`, mode 600 in a folder of mode 700. Nothing secret is shipped or committed, and a
sim and haptic server of the same installation (the same account) meet without set-up. For
two hosts, copy `sim.password` to the sim's host (docs/security.md).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
import time
from pathlib import Path

LOCAL = "@local"  # a network config's name for this installation's credential files
SIM_USER = "sim"
PASSWORD_FILE = "sim.password"
USERS_FILE = "users.txt"
#: another process may be writing the password this very moment: wait this long for it
WRITE_WAIT_S = 2.0


class CredentialsError(ValueError):
    """The local credentials cannot be made or are not private: names the path."""


def credentials_dir() -> Path:
    """Where this installation's credentials live (not created)."""
    override = os.environ.get("HAPTIC_CREDENTIALS_DIR")
    if override:
        return Path(override)
    config = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(config) / "haptic-local-model" / "credentials"


def local_credentials() -> tuple[Path, Path]:
    """(users file, sim password file) of this installation, made now if missing.

    Safe against two processes starting at once: the password file is created exclusively;
    the loser reads the winner's. The users file is derived from it."""
    folder = credentials_dir()
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as exc:
        raise CredentialsError(f"{folder}: cannot make the credentials folder ({exc})") from None
    _require_private(folder, 0o077)
    password_path = folder / PASSWORD_FILE
    password = _create_or_read(password_path)
    users_path = folder / USERS_FILE
    line = f"{SIM_USER}:{password}\n"
    if not users_path.is_file() or users_path.read_text() != line:
        _write_private(users_path, line)
    _require_private(users_path, 0o077)
    return users_path, password_path


def _create_or_read(path: Path) -> str:
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        _require_private(path, 0o077)
        end = time.monotonic() + WRITE_WAIT_S
        while True:  # the other process may not have written it yet
            lines = path.read_text().splitlines()
            if lines and lines[0]:
                return lines[0]
            if time.monotonic() > end:
                raise CredentialsError(f"{path}: empty password file") from None
            time.sleep(0.01)
    password = secrets.token_urlsafe(24)
    with os.fdopen(fd, "w") as fh:
        fh.write(password + "\n")
        fh.flush()
        os.fsync(fh.fileno())
    return password


def _write_private(path: Path, text: str) -> None:
    """Write `text` to `path` (mode 600) atomically: a reader sees the old or the new file."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    try:
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def _require_private(path: Path, others: int) -> None:
    mode = stat.S_IMODE(path.stat().st_mode)
    if mode & others:
        raise CredentialsError(
            f"{path}: readable by others (mode {mode:o}); credentials must be the user's only "
            f"(chmod {'700' if path.is_dir() else '600'} {path})"
        )
