"""`haptic-server`: the 1 kHz haptic loop against a simulated device, over Zenoh."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from haptic_local_model.haptic_server.view_address import add_view_args, view_address
from haptic_local_model.shared.cli import (
    EXIT_FAILED,
    EXIT_LOG_FAILED,
    add_config_args,
    done_with_signals,
    emit,
    log_file,
    run_main,
    seconds,
    write_summary,
)
from haptic_local_model.shared.config import load_scene, load_user, resolve, scene_text
from haptic_local_model.shared.net.config import load_network, on_port

if TYPE_CHECKING:
    from haptic_local_model.device_models.base import Device


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="haptic-server", description=__doc__)
    add_config_args(parser, rate=True)
    parser.add_argument(
        "--log", type=log_file, default=None, help="MCAP log path (default: no log)"
    )
    parser.add_argument(
        "--duration", type=seconds, default=None,
        help="stop this many seconds after the first update (or 60 s later without one)",
    )  # fmt: skip
    parser.add_argument("--summary-json", type=Path, default=None)
    add_view_args(parser)
    parser.add_argument("--inject-leak", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--inject-nan-after", type=seconds, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    def body() -> int:
        from haptic_local_model.device_models.base import DeviceError, SafeStopError
        from haptic_local_model.device_models.registry import load_device
        from haptic_local_model.haptic_server.logger import LogStartError

        # every config checked first: a typo must not open (or calibrate) a real device
        scene = load_scene(args.scene, args.haptic_rate)
        user = load_user(args.user)
        network = load_network(args.network, roles=("haptic",))
        if args.port is not None:
            network = on_port(network, args.port)
        try:  # its config is checked before the driver is built (and opens its device)
            device = load_device(args.device)
        except DeviceError as exc:  # the driver has closed what it opened
            print(f"haptic-server: device error: {exc}", file=sys.stderr)
            return EXIT_FAILED
        try:
            return serve(device, scene, user, network)
        except DeviceError as exc:  # the loop sent it safe, or tried to: once more here
            try:
                device.safe_stop()
            except SafeStopError as stop_exc:
                print(f"haptic-server: device error: {exc}; the safe stop FAILED: {stop_exc}: "
                      "the device may still apply force", file=sys.stderr)  # fmt: skip
                return EXIT_FAILED
            if isinstance(exc, SafeStopError):  # the first try failed, the second worked
                print(f"haptic-server: {exc}; a second safe stop succeeded", file=sys.stderr)
            else:
                print(f"haptic-server: device error: {exc}; the device is in its safe state",
                      file=sys.stderr)  # fmt: skip
            return EXIT_FAILED
        except LogStartError as exc:  # the loop never started: nothing was commanded
            device.safe_stop()
            print(f"haptic-server: {exc}", file=sys.stderr)
            return EXIT_FAILED
        except BaseException:
            device.safe_stop()  # whatever failed, a real device is left without force
            raise

    def serve(device: Device, scene: Any, user: Any, network: Any) -> int:
        from haptic_local_model.device_models.base import SimulatedDevice
        from haptic_local_model.device_models.registry import device_config, load_device
        from haptic_local_model.haptic_server.loop import HapticServer, InjectedFaults, ServerExtras

        if network.unauthenticated_insecure:
            print(
                f"warning: {args.network}: unauthenticated_insecure: anyone who reaches "
                f"{', '.join(network.haptic.listen)} can drive the device",
                file=sys.stderr,
                flush=True,
            )
        configs = {
            "scene": scene_text(resolve("scenes", args.scene), args.haptic_rate),
            "device": device_config(args.device).read_text(),
            "user": resolve("users", args.user).read_text(),
            "network": resolve("network", args.network).read_text(),
        }
        faults = InjectedFaults(2048 if args.inject_leak else 0, args.inject_nan_after)
        extras = ServerExtras(view=view_address(args), faults=faults)
        server = HapticServer(scene, device, user, network, args.log, configs, extras)
        signal.signal(signal.SIGTERM, server.request_stop)
        signal.signal(signal.SIGINT, server.request_stop)
        # the warm-up compiles on a throwaway engine and device: a hardware driver is built
        # once only (building one opens the hardware), its loop's kernels warm on the ideal
        simulated = isinstance(device, SimulatedDevice)
        summary = server.run(
            args.duration,
            ready=lambda: emit("ready", process="haptic", loop_cpu=server.stats.loop_cpu),
            warm=lambda: server.warm_up(
                lambda: load_device(args.device if simulated else "ideal"), user
            ),
        )
        emit("stopped", process="haptic", **summary)
        if not write_summary(args.summary_json, summary, "haptic-server"):
            return EXIT_FAILED
        if summary["io_lost"]:
            print("haptic-server: the I/O process died; the run was stopped", file=sys.stderr)
            return EXIT_FAILED
        if summary["log_failed"]:
            return EXIT_LOG_FAILED
        return 0

    return done_with_signals(run_main(body), argv)


if __name__ == "__main__":
    sys.exit(main())
