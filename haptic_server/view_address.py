"""The live view's address on the command line: `--view` and its ports (add_view_args), and
where the view is served (ViewAddress). Apart from the view itself (live_view.py) so that a
command line that parses them imports neither numba nor the view's modules: haptic-run's
parent process starts its servers without either.
"""

from __future__ import annotations

import argparse
import importlib.util
from dataclasses import dataclass

from haptic_local_model.shared.config import ConfigError

GRPC_PORT = 9876  # Rerun's defaults
WEB_PORT = 9090


@dataclass(frozen=True)
class ViewAddress:
    """Where the view is served: the browser opens `url`."""

    bind: str = "127.0.0.1"
    web_port: int = WEB_PORT
    grpc_port: int = GRPC_PORT

    @property
    def host(self) -> str:
        return "127.0.0.1" if self.bind in ("0.0.0.0", "::") else self.bind

    @property
    def grpc_url(self) -> str:
        return f"rerun+http://{self.host}:{self.grpc_port}/proxy"

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.web_port}/?url={self.grpc_url}"

    def argv(self) -> list[str]:
        """The options (add_view_args) that ask a child for this view."""
        return [
            "--view", "--view-port", str(self.web_port), "--view-grpc-port", str(self.grpc_port),
            "--view-bind", self.bind,
        ]  # fmt: skip


def add_view_args(parser: argparse.ArgumentParser, what: str = "the run") -> None:
    """--view, --view-port, --view-grpc-port, --view-bind."""
    parser.add_argument(
        "--view", action="store_true",
        help=f"draw {what} live in a browser (Rerun's web viewer; the URL is printed)",
    )  # fmt: skip
    parser.add_argument(
        "--view-port", type=_port, default=WEB_PORT, metavar="PORT",
        help=f"the view's web page port (default {WEB_PORT})",
    )  # fmt: skip
    parser.add_argument(
        "--view-grpc-port", type=_port, default=GRPC_PORT, metavar="PORT",
        help=f"the view's data port (default {GRPC_PORT})",
    )  # fmt: skip
    parser.add_argument(
        "--view-bind", default="127.0.0.1", metavar="ADDR",
        help="the address the view listens on (default 127.0.0.1: this machine only)",
    )  # fmt: skip


#: what installs the live view's SDK (an extra: 660 MB with pyarrow, which a run without a
#: view does not need)
VIEW_EXTRA = "pip install 'haptic-local-model[view]' (in a checkout: make view)"


def view_address(args: argparse.Namespace) -> ViewAddress | None:
    """The view asked for on the command line (None without --view); refused, saying what to
    install, where the Rerun SDK is not installed."""
    if not args.view:
        return None
    if importlib.util.find_spec("rerun") is None:
        raise ConfigError("command line", "--view", f"needs the Rerun SDK: {VIEW_EXTRA}")
    if args.view_port == args.view_grpc_port:
        raise ConfigError("command line", "--view-port", "must differ from --view-grpc-port")
    return ViewAddress(args.view_bind, args.view_port, args.view_grpc_port)


def _port(text: str) -> int:
    port = int(text)
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text} is not a port (1-65535)")
    return port
