"""hapticbench: a named suite of haptic rendering cases with a versioned JSON result.

A **case** is a scene, a simulated device, a simulated hand and a run length, with the
reference its error is taken against and the metrics it reports (benchmarks/front.py says
how each reference is made):

- `wall_impact_push`: a 2 N push into a stiff wall; the device's penetration against the
  closed form F/K (peak at impact, error after 2 s, settling, contact losses, port energy);
- `linkage_held`: the linkage held at its distal link, pushed with 0.4 N; the device against
  the VM alone integrated independently (RNEA and solve_ivp);
- `linkage_singular`: the same hold pushed with 0.4 N along +y, which straightens the elbow
  through the hold's rank loss; the device against the same reference over the run and
  within 0.25 s of the reference's smallest singular value (benchmarks/suite_metrics.py);
- `testbed_swing`: the hand swinging the tool into the testbed's walls; the device against
  the same pymunk world stepped at 10 kHz with the hand's spring on the tool;
- `slide_friction`, `moving_wall`, `grasp_two_devices`: the box slid along a floor against
  mu_k N, the rectangle pushed onto an oscillating wall against the wall's law, two devices
  squeezing a box against g - 2 mu N / m and its drift (benchmarks/suite_metrics.py);
- `coaster`: seed 003's three-car train on its loop (`coaster_loop`), shoved by the hand
  `push_car` through the ideal device; the lead car's arc length, the device and the energy
  the push gave the train against a transparent device at 10 kHz (benchmarks/suite_coaster.py).

Every row carries the port energy and the passivity observer's margin; a method that cannot
render a case (the grasp's two devices; the coaster's train, which pymunk does not hold)
raises NotApplicableError and its row says why. The
full suite adds each method's stable wall stiffness at 250, 500 and 1000 Hz
(benchmarks/suite_stiffness.py).

A **method** (a baseline) is a function from a case to the records of its run
(`MethodRun`: the haptic loop's TICK_DTYPE records, the scene as rendered, the cost): the
built-ins are the local model, the three ways of benchmarks/front.py, Isaac Lab's Haply
coupling (benchmarks/peers.py) and SOFA's LCPForceFeedback (benchmarks/peers_sofa.py);
another project's coupling is one more function given to `register_baseline`, and the suite's table and JSON
carry it with no change here (docs/bench/hapticbench.md: "Submit your renderer").

Every result carries `schema_version`, the build (package version and git commit), the
machine and the seed, and passes `validate` against `RESULT_SCHEMA` (a subset of JSON
Schema). Error figures are deterministic on one build and machine (the virtual clock);
cost figures are wall-clock and vary run to run.

    haptic-bench --suite hapticbench [--out DIR]   (or --suite reduced: two short cases)
    haptic-bench --suite hapticbench --cases coaster,wall_impact_push [--out DIR]

`--cases` runs only the named cases of the suite (every method; without the stable stiffness),
for a case being worked on: its report is not the suite's.
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.benchmarks import (
    front,
    peers,
    peers_sofa,
    suite_coaster,
    suite_metrics,
    suite_stiffness,
)
from haptic_local_model.benchmarks.linkage import reference_error_mm
from haptic_local_model.benchmarks.suite_records import Case, MethodRun, NotApplicableError
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.shared import __version__
from haptic_local_model.shared.config import SceneConfig, load_scene, load_user

SUITE_NAME = "hapticbench"
#: 2: the port energy and the passivity observer's margin in every row's errors, a row
#: may say why its method does not apply instead of figures, cases have `ports`
SCHEMA_VERSION = 2
#: the suite's seed: no shipped case draws random numbers (its devices are noiseless, its
#: hands scripted); it is recorded so a case that does (a noisy device) is seeded from it
SEED = 0


Baseline = Callable[[Case], MethodRun]


@dataclass(frozen=True)
class Method:
    name: str
    description: str
    run: Baseline


CASES = (
    Case("wall_impact_push", "wall_push", "ideal", "push_2n", 5.0,
         "closed form: steady penetration F/K", "peak_over_fk"),
    Case("linkage_held", "linkage_distal", "ideal_identity", "push_04n", 5.0,
         "independent integration: the VM alone, RNEA and solve_ivp", "rms_mm"),
    Case("linkage_singular", "linkage_distal", "ideal_identity", "push_04n_up", 5.0,
         "independent integration: the VM alone, RNEA and solve_ivp, through the elbow's"
         " rank loss at 1.81 s", "rms_singular_mm"),
    Case("testbed_swing", "testbed", "ideal", "swing", 5.0,
         "fine-step simulation: pymunk at 10 kHz, the hand's spring on the tool", "rms_first_s_mm"),
    Case("slide_friction", "wall_slide", "ideal", "slide", 3.5,
         "closed form: the rendered tangential force mu_k N while sliding", "mu_rel_error"),
    Case("moving_wall", "wall_moving", "ideal", "push_2n", 5.0,
         "the wall's motion law: the face at x0 + A sin(wt), inside it by (F - m a) / K",
         "rms_mm"),
    Case("grasp_two_devices", "grasp_vertical", "ideal", "squeeze_left_2n+squeeze_right_2n",
         10.15, "closed form: the box slipping at g - 2 mu N / m; held above the cone, no drift",
         "slip_accel_rel_error", ports=2),
    Case("coaster", suite_coaster.SCENE, "ideal", "push_car", 4.0,
         "fine-step simulation: a transparent device, the finger on the cars by their material's"
         " contact law, the train by the arc-length Lagrangian (RK4 at 10 kHz)", "rms_mm"),
)  # fmt: skip
#: the reduced suite `make test` runs (tests/test_hapticbench.py): two cases, short runs
REDUCED = (
    Case("wall_impact_push", "wall_push", "ideal", "push_2n", 2.5,
         "closed form: steady penetration F/K", "peak_over_fk"),
    Case("linkage_held", "linkage_distal", "ideal_identity", "push_04n", 1.0,
         "independent integration: the VM alone, RNEA and solve_ivp", "rms_mm"),
)  # fmt: skip
SUITES = {"hapticbench": CASES, "reduced": REDUCED}


def select(cases: tuple[Case, ...], names: tuple[str, ...]) -> tuple[Case, ...]:
    """The named cases of a suite, in its order (all of them when none is named); an unknown
    name is refused with the suite's names."""
    known = [c.name for c in cases]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(
            f"hapticbench: no case {', '.join(unknown)} in the suite: {', '.join(known)}"
        )
    return tuple(c for c in cases if not names or c.name in names)


#: the registry of methods, in table order: the built-ins below, then any plug-in
BASELINES: dict[str, Method] = {}


def register_baseline(name: str, description: str, run: Baseline) -> None:
    """Add a method to every later run of the suite (a plug-in: another project's coupling)."""
    if name in BASELINES:
        raise ValueError(f"hapticbench: a baseline named {name!r} is already registered")
    BASELINES[name] = Method(name, description, run)


@contextmanager
def baseline(name: str, description: str, run: Baseline) -> Iterator[None]:
    """A baseline registered for the duration of a `with` block (tests, one-off runs)."""
    register_baseline(name, description, run)
    try:
        yield
    finally:
        del BASELINES[name]


def front_way(way: str, sim_hz: float) -> Baseline:
    """A way of benchmarks/front.py as a baseline: its configuration (with the substeps its
    coupling needs to be stable, doubled until the run is), its device hold, its cost."""

    configured: dict[Case, SceneConfig] = {}  # the stable configuration, found once a case

    def run(case: Case) -> MethodRun:
        if case.ports != 1:
            if way == "local_model":  # this project's two devices: the ports' co-simulation
                return suite_metrics.grasp_run(case)
            raise NotApplicableError(
                "a coupling of one device to the sim's tool: the case has two devices on one"
                " object, which needs the tools and the object solved together at 1 kHz"
            )
        if case not in configured:
            configured[case] = _configured(case, way, sim_hz)
        scene = configured[case]
        device = front.device_for(case.device, way)
        result = run_virtual(scene, device, load_user(case.user), case.seconds)
        return MethodRun(
            result.ticks, scene, front.cost_ms(result, way), scene.sim_rate_hz, scene.sim_substeps
        )

    return run


def _configured(case: Case, way: str, sim_hz: float) -> SceneConfig:
    """The case's scene as `way` renders it. A mechanism (the coaster's train) is pushed by
    the god-object's finger alone: the local model renders its scene as it ships (its
    god_object method and sim rate); no coupling to pymunk renders one."""
    scene = load_scene(case.scene)
    if suite_coaster.has_mechanism(scene):
        if way != "local_model":
            raise NotApplicableError(suite_coaster.NO_TRAIN_IN_PYMUNK)
        return scene
    return front.stable_configuration(scene, way, sim_hz, case.device, case.user, case.seconds)


#: the built-in methods: benchmarks/front.py's ways, the local model at 60 Hz; then the
#: peers written as they write them (benchmarks/peers.py, benchmarks/peers_sofa.py)
BUILT_IN = (("local_model", 60.0), ("pymunk_in_loop", front.HAPTIC_HZ), ("vc_zoh", 60.0),
            ("vc_foh", 60.0))  # fmt: skip
for way, hz in BUILT_IN:
    register_baseline(way, front.WAYS[way], front_way(way, hz))
register_baseline("isaac_haply", peers.ISAAC_HAPLY, peers.isaac_haply)
register_baseline("sofa_lcp", peers_sofa.SOFA_LCP, peers_sofa.sofa_lcp)
BUILT_IN_NAMES = tuple(BASELINES)  # what a run without plug-ins renders every case with


def case_errors(case: Case, run: MethodRun, reference: np.ndarray | None) -> dict[str, float]:
    """The case's error metrics over the run's records (None in JSON where undefined)."""
    if case.ports != 1:
        return suite_metrics.grasp_errors(case, run)
    scene = run.scene
    assert isinstance(scene, SceneConfig)
    window = scene.safety.passivity_window_s
    return {
        **_case_errors(case, scene, run.ticks, reference),
        **suite_metrics.port_metrics(run.ticks, window, case.device),
    }


def _case_errors(
    case: Case, scene: SceneConfig, ticks: np.ndarray, reference: np.ndarray | None
) -> dict[str, float]:
    if case.scene == "wall_push":
        return front.wall_transient(scene, ticks)
    if case.headline == "rms_singular_mm":
        return suite_metrics.singular_errors(scene, case.user, ticks)
    if case.scene == "linkage_distal":
        err = reference_error_mm(scene, ticks, float(ticks["t"][-1]) + 1e-9, "device_pose")
        return {"rms_mm": float(np.sqrt(np.mean(err**2))), "max_mm": float(err.max())}
    if case.scene == "wall_slide":
        return suite_metrics.slide_errors(scene, ticks)
    if case.scene == "wall_moving":
        return suite_metrics.moving_wall_errors(scene, case.device, ticks)
    if reference is None:
        raise ValueError(f"hapticbench: case {case.name!r} needs its fine-step reference")
    if case.scene == suite_coaster.SCENE:
        return suite_coaster.coaster_errors(scene, case.device, ticks, reference)
    n = min(len(reference), len(ticks))
    err = 1e3 * np.hypot(*(ticks["device_pose"][:n, :2] - reference[:n]).T)
    first = ticks["t"][:n] < front.TESTBED_FIRST_S
    apart = np.flatnonzero(err > front.TESTBED_BAND_MM)
    return {
        "rms_first_s_mm": float(np.sqrt(np.mean(err[first] ** 2))),
        "follows_ms": 1e3 * float(ticks["t"][apart[0]] if apart.size else ticks["t"][n - 1]),
        "rms_mm": float(np.sqrt(np.mean(err**2))),
    }


def case_reference(case: Case) -> np.ndarray | None:
    """The fine-step reference path of a case that needs one (computed once per case)."""
    if case.scene == suite_coaster.SCENE:
        scene = load_scene(case.scene)
        return suite_coaster.reference(scene, case.device, case.user, case.seconds)
    if case.scene != "testbed":
        return None
    return front.testbed_reference(case.scene, case.device, case.user, case.seconds)


def _finite_or_none(errors: dict[str, float]) -> dict[str, float | None]:
    return {k: (v if math.isfinite(v) else None) for k, v in errors.items()}


def _row(case: Case, method: Method, reference: np.ndarray | None, repeat: int) -> dict[str, Any]:
    """A case rendered by a method `repeat` times: its result row (or why it does not apply)."""
    costs = []
    for _ in range(repeat):
        try:
            run = method.run(case)
        except NotApplicableError as why:
            return {"case": case.name, "method": method.name, "not_applicable": str(why)}
        costs.append(run.cost_ms_per_sim_s)
    return {
        "case": case.name, "method": method.name,
        "sim_hz": run.sim_hz, "substeps": run.substeps,
        "errors": _finite_or_none(case_errors(case, run, reference)),
        "cost_ms_per_sim_s": {"median": float(np.median(costs)),
                              "min": min(costs), "max": max(costs), "runs": repeat},
    }  # fmt: skip


def run_suite(cases: tuple[Case, ...], repeat: int = 1, stiffness: bool = False) -> dict[str, Any]:
    """Every case rendered by every registered method: the result document (RESULT_SCHEMA).
    The errors are the last round's (every round gives the same); the cost is the median
    of `repeat` rounds with its spread (min, max). A method that raises NotApplicableError
    for a case gives that case a row with its reason instead. With `stiffness`, every
    method's stable wall stiffness at 250, 500 and 1000 Hz (benchmarks/suite_stiffness.py)."""
    methods = list(BASELINES.values())
    # one short run first, thrown away: the first run of a process pays for loading the
    # compiled kernels, which is not the cost of any method
    warm = next((c for c in cases if c.ports == 1), None)
    if warm is not None:
        run_virtual(load_scene(warm.scene), load_device(warm.device), load_user(warm.user), 0.2)
    rows: list[dict[str, Any]] = []
    for case in cases:
        reference = case_reference(case)
        rows.extend(_row(case, method, reference, repeat) for method in methods)
    stiff = {"stable_stiffness": suite_stiffness.stiffness_rows(methods)} if stiffness else {}
    return {
        "schema_version": SCHEMA_VERSION,
        "suite": SUITE_NAME,
        "build": build_info(),
        "machine": machine_info(),
        "seed": SEED,
        "haptic_hz": front.HAPTIC_HZ,
        "cases": [
            {
                "name": c.name,
                "scene": c.scene,
                "device": c.device,
                "user": c.user,
                "seconds": c.seconds,
                "reference": c.reference,
                "headline": c.headline,
                "ports": c.ports,
            }
            for c in cases
        ],
        "methods": [{"name": m.name, "description": m.description} for m in methods],
        "results": rows,
        **stiff,
    }


def build_info() -> dict[str, Any]:
    """The package version and, in a git checkout, the commit and whether it was modified."""
    here = Path(__file__).resolve().parent
    commit, dirty = None, None
    try:
        git = ["git", "-C", str(here)]
        out = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True)
        if out.returncode == 0:
            commit = out.stdout.strip()
            status = subprocess.run(
                [*git, "status", "--porcelain", "--untracked-files=no"],
                capture_output=True, text=True,
            )  # fmt: skip
            dirty = bool(status.stdout.strip())
    except OSError:  # no git: an installed package, the version alone names the build
        pass
    return {"package_version": __version__, "git_commit": commit, "git_dirty": dirty}


def machine_info() -> dict[str, Any]:
    import numba

    cpu = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "platform": platform.platform(), "machine": platform.machine(), "cpu": cpu,
        "cpu_count": os.cpu_count() or 0, "python": platform.python_version(),
        "numpy": np.__version__, "numba": numba.__version__,
    }  # fmt: skip


_NUMBER = {"type": "number"}
_NULLABLE_NUMBER = {"type": ["number", "null"]}
#: the result document, as JSON Schema (draft 2020-12 keywords: a subset `validate` checks;
#: any JSON Schema validator accepts it too). Bump SCHEMA_VERSION on any change of meaning.
RESULT_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "hapticbench result",
    "type": "object",
    "required": [
        "schema_version",
        "suite",
        "build",
        "machine",
        "seed",
        "haptic_hz",
        "cases",
        "methods",
        "results",
    ],
    "additionalProperties": False,
    "properties": {
        "schema_version": {"const": SCHEMA_VERSION},
        "suite": {"const": SUITE_NAME},
        "build": {
            "type": "object",
            "required": ["package_version", "git_commit", "git_dirty"],
            "additionalProperties": False,
            "properties": {
                "package_version": {"type": "string"},
                "git_commit": {"type": ["string", "null"]},
                "git_dirty": {"type": ["boolean", "null"]},
            },
        },
        "machine": {
            "type": "object",
            "required": ["platform", "machine", "cpu", "cpu_count", "python", "numpy", "numba"],
            "properties": {"cpu_count": {"type": "integer", "minimum": 0}},
        },
        "seed": {"type": "integer"},
        "haptic_hz": _NUMBER,
        "cases": {
            "type": "array",
            "minItems": 1,
            "items": {
                "type": "object",
                "additionalProperties": False,
                "required": [
                    "name",
                    "scene",
                    "device",
                    "user",
                    "seconds",
                    "reference",
                    "headline",
                    "ports",
                ],
                "properties": {
                    "name": {"type": "string"},
                    "scene": {"type": "string"},
                    "device": {"type": "string"},
                    "user": {"type": "string"},
                    "seconds": {"type": "number", "exclusiveMinimum": 0},
                    "reference": {"type": "string"},
                    "headline": {"type": "string"},
                    "ports": {"type": "integer", "minimum": 1},
                },
            },
        },
        "methods": {
            "type": "array",
            "minItems": 1,
            "items": {
                "type": "object",
                "required": ["name", "description"],
                "additionalProperties": False,
                "properties": {"name": {"type": "string"}, "description": {"type": "string"}},
            },
        },
        "stable_stiffness": {
            "type": "array",
            "items": {
                "type": "object",
                "additionalProperties": False,
                "required": ["method", "rate_hz"],
                "oneOf": [
                    {"required": ["not_applicable"]},
                    {"required": ["stable_to_n_per_m", "felt_n_per_m", "capped", "probes"]},
                ],
                "properties": {
                    "method": {"type": "string"},
                    "rate_hz": {"type": "number", "exclusiveMinimum": 0},
                    "not_applicable": {"type": "string", "minLength": 1},
                    "stable_to_n_per_m": _NULLABLE_NUMBER,
                    "felt_n_per_m": _NULLABLE_NUMBER,
                    "capped": {"type": "boolean"},
                    "probes": {"type": "integer", "minimum": 1},
                },
            },
        },
        "results": {
            "type": "array",
            "items": {
                "type": "object",
                "additionalProperties": False,
                "required": ["case", "method"],
                # a row has figures, or says why its method does not render its case
                "oneOf": [
                    {"required": ["not_applicable"]},
                    {"required": ["sim_hz", "substeps", "errors", "cost_ms_per_sim_s"]},
                ],
                "properties": {
                    "case": {"type": "string"},
                    "method": {"type": "string"},
                    "not_applicable": {"type": "string", "minLength": 1},
                    "sim_hz": {"type": "number", "exclusiveMinimum": 0},
                    "substeps": {"type": "integer", "minimum": 1},
                    "errors": {"type": "object", "additionalProperties": _NULLABLE_NUMBER},
                    "cost_ms_per_sim_s": {
                        "type": "object",
                        "required": ["median", "min", "max", "runs"],
                        "additionalProperties": False,
                        "properties": {
                            "median": _NUMBER,
                            "min": _NUMBER,
                            "max": _NUMBER,
                            "runs": {"type": "integer", "minimum": 1},
                        },
                    },
                },
            },
        },
    },
}

_TYPES: dict[str, Callable[[Any], bool]] = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, int | float) and not isinstance(v, bool),
}


def validate(doc: Any, schema: dict[str, Any] = RESULT_SCHEMA, where: str = "$") -> None:
    """Raise ValueError naming the first place `doc` breaks `schema` (the keywords
    RESULT_SCHEMA uses: type, const, required, properties, additionalProperties, items,
    minItems, minLength, minimum, exclusiveMinimum, oneOf)."""

    def fail(message: str) -> None:
        raise ValueError(f"hapticbench result: {where}: {message}")

    types = schema.get("type")
    if types is not None:
        names = [types] if isinstance(types, str) else types
        if not any(_TYPES[t](doc) for t in names):
            fail(f"expected {' or '.join(names)}, got {type(doc).__name__}")
    if "const" in schema and doc != schema["const"]:
        fail(f"expected {schema['const']!r}, got {doc!r}")
    if "minimum" in schema and doc < schema["minimum"]:
        fail(f"{doc} is below {schema['minimum']}")
    if "exclusiveMinimum" in schema and doc <= schema["exclusiveMinimum"]:
        fail(f"{doc} is not above {schema['exclusiveMinimum']}")
    if "minLength" in schema and len(doc) < schema["minLength"]:
        fail(f"shorter than {schema['minLength']}")
    if isinstance(doc, dict):
        for key in schema.get("required", ()):
            if key not in doc:
                fail(f"missing key {key!r}")
        props = schema.get("properties", {})
        extra = schema.get("additionalProperties", True)
        for key, value in doc.items():
            if key in props:
                validate(value, props[key], f"{where}.{key}")
            elif extra is False:
                fail(f"unknown key {key!r}")
            elif isinstance(extra, dict):
                validate(value, extra, f"{where}.{key}")
    if isinstance(doc, list):
        if len(doc) < schema.get("minItems", 0):
            fail(f"fewer than {schema['minItems']} items")
        for i, item in enumerate(doc):
            validate(item, schema.get("items", {}), f"{where}[{i}]")
    if "oneOf" in schema:
        matched = sum(_valid(doc, alternative) for alternative in schema["oneOf"])
        if matched != 1:
            fail(f"matches {matched} of oneOf's {len(schema['oneOf'])} alternatives, not 1")


def _valid(doc: Any, schema: dict[str, Any]) -> bool:
    try:
        validate(doc, schema)
    except ValueError:
        return False
    return True


def error_figures(doc: dict[str, Any]) -> dict[tuple[str, str], dict[str, Any]]:
    """The deterministic part of a result: every (case, method)'s errors (or why the method
    does not apply)."""
    return {
        (r["case"], r["method"]): r["errors"] if "errors" in r else {"n/a": r["not_applicable"]}
        for r in doc["results"]
    }


def table(doc: dict[str, Any]) -> list[str]:
    """Markdown: one row per case and method, the headline error, cost and every metric."""
    headline = {c["name"]: c["headline"] for c in doc["cases"]}
    described = {m["name"]: m["description"] for m in doc["methods"]}
    lines = [
        "| case | method | sim Hz | substeps | headline error | cost ms / sim s (median, min-max) | errors |",
        "|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for r in doc["results"]:
        key = headline[r["case"]]
        if "not_applicable" in r:
            lines.append(f"| {r['case']} | {described[r['method']]} | - | - | does not apply:"
                         f" {r['not_applicable']} | - | - |")  # fmt: skip
            continue
        c = r["cost_ms_per_sim_s"]
        errs = ", ".join(f"{k} {_fmt(v)}" for k, v in r["errors"].items())
        lines.append(
            f"| {r['case']} | {described[r['method']]} | {r['sim_hz']:g} | {r['substeps']} "
            f"| {key} {_fmt(r['errors'].get(key))} | {c['median']:.1f} ({c['min']:.1f}-{c['max']:.1f}) "
            f"| {errs} |"
        )
    return lines


def pareto(doc: dict[str, Any]) -> list[str]:
    """A sentence per case: the methods on its error-vs-cost front (headline error against
    median cost) and, for each method off it, one that beats it on both."""
    lines = []
    for case in doc["cases"]:
        key = case["headline"]
        points = [
            (r["method"], r["errors"].get(key), r["cost_ms_per_sim_s"]["median"])
            for r in doc["results"]
            if r["case"] == case["name"] and r.get("errors", {}).get(key) is not None
        ]
        absent = [r["method"] for r in doc["results"]
                  if r["case"] == case["name"] and "not_applicable" in r]  # fmt: skip
        on, off = [], []
        for name, err, cost in points:
            better = [n for n, e, c in points if n != name and e <= err and c <= cost
                      and (e < err or c < cost)]  # fmt: skip
            if better:
                off.append(f"{name} (beaten by {better[0]})")
            else:
                on.append(name)
        lines.append(
            f"- {case['name']} ({key} against cost): on the front {', '.join(on)}"
            + (f"; off it {', '.join(off)}" if off else "")
            + (f"; does not apply {', '.join(absent)}" if absent else "")
        )
    return lines


def case_paragraphs(doc: dict[str, Any]) -> list[str]:
    """A paragraph per case that has a writer in CASE_TEXT: who wins it and why, from the
    result's own figures."""
    lines = []
    for case in doc["cases"]:
        writer = CASE_TEXT.get(case["name"])
        rows = [r for r in doc["results"] if r["case"] == case["name"]]
        if writer is not None and rows:
            lines += [writer(case, rows), ""]
    return lines


def _coaster_text(case: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    key = case["headline"]
    rendered = sorted((r for r in rows if "errors" in r), key=lambda r: r["errors"][key])
    absent = [r["method"] for r in rows if "not_applicable" in r]
    if not rendered:
        return f"- **{case['name']}**: no method renders it ({', '.join(absent)} do not apply)."
    best, e = rendered[0], rendered[0]["errors"]
    others = "; ".join(f"{r['method']} {_fmt(r['errors'][key])} mm" for r in rendered[1:])
    return (
        f"- **{case['name']}**: {best['method']} follows the lead car closest to the transparent"
        f" device: {_fmt(e[key])} mm RMS over the run, {_fmt(e['push_rms_mm'])} mm over the push,"
        f" {_fmt(e['max_mm'])} mm at most; the energy the push gave the train is off by"
        f" {100 * e['energy_given_rel_error']:.2g} % and the device within"
        f" {_fmt(e['device_push_rms_mm'])} mm RMS of the reference's finger, at"
        f" {best['cost_ms_per_sim_s']['median']:.1f} ms per simulated second"
        + (f" (then {others})" if others else "")
        + ". The local model's error is its god-object's"
        + ("" if best["method"] == "local_model" else " (it does not win here)")
        + ": the hand pushes the car through a 1 kN/m spring to the proxy where the reference's"
        " finger is the car's 15 kN/m contact, and the implicit coupling of the push to the"
        " train keeps part of its work (never adds)."
        + (f" {', '.join(absent)} do not apply: pymunk holds no train (the sim moves the cars"
           " kinematically along the haptic side's avar), so a coupling to the sim's tool has"
           " nothing it could push." if absent else "")
    )  # fmt: skip


#: the per-case paragraph writers of the report (case name: writer of its rows)
CASE_TEXT: dict[str, Callable[[dict[str, Any], list[dict[str, Any]]], str]] = {
    "coaster": _coaster_text
}


def stiffness_table(doc: dict[str, Any]) -> list[str]:
    """Markdown: the stable wall stiffness of every method at every rate, and what the hand
    felt there (nothing when the result has none)."""
    rows = doc.get("stable_stiffness")
    if not rows:
        return []
    rates = sorted({r["rate_hz"] for r in rows})
    lines = [
        "The stable wall stiffness (benchmarks/suite_stiffness.py: the stiffest `wall_push`"
        " wall the method renders with the device taking net energy from the hand and coming"
        " to rest; >= at the top of the search; in brackets the stiffness the hand felt there,"
        " the push over the device's steady depth):", "",
        "| method | " + " | ".join(f"{r:g} Hz" for r in rates) + " |",
        "|---|" + "---|" * len(rates),
    ]  # fmt: skip
    for name in dict.fromkeys(r["method"] for r in rows):
        cells = []
        for rate in rates:
            r = next(x for x in rows if x["method"] == name and x["rate_hz"] == rate)
            cells.append(_stiffness_cell(r))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def _stiffness_cell(r: dict[str, Any]) -> str:
    if "not_applicable" in r:
        return "does not apply"
    if r["stable_to_n_per_m"] is None:
        return "none stable"
    felt = r["felt_n_per_m"]
    felt_text = "not in the wall" if felt is None else f"{felt:.3g}"
    return f"{'>= ' if r['capped'] else ''}{r['stable_to_n_per_m']:.3g} N/m ({felt_text})"


def _fmt(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.4g}"


def plot(doc: dict[str, Any], out: Path) -> Path:
    """The headline error against the cost, a panel per case, a marker per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = doc["cases"]
    cols = min(3, len(cases))
    rows = -(-len(cases) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.3 * cols, 4.6 * rows), squeeze=False)
    for ax in axes.flat[len(cases) :]:
        ax.set_visible(False)
    marks = "osv^Dpx*+h"
    order = [m["name"] for m in doc["methods"]]
    for ax, case in zip(axes.flat, cases, strict=False):
        for r in doc["results"]:
            value = r.get("errors", {}).get(case["headline"])
            if r["case"] != case["name"] or value is None:
                continue
            mark = marks[order.index(r["method"]) % len(marks)]
            ax.loglog(r["cost_ms_per_sim_s"]["median"], max(value, 1e-4), mark, ms=8,
                      label=r["method"])  # fmt: skip
        ax.set_xlabel("cost per simulated second (ms)")
        ax.set_ylabel(case["headline"])
        ax.set_title(f"{case['name']}: error against cost")
        ax.legend(fontsize=7)
    fig.tight_layout()
    path = out / "hapticbench.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write(doc: dict[str, Any], out: Path, command: str, wall_s: float) -> str:
    """The JSON, its schema, the plot and the markdown report in `out`; returns the report."""
    validate(doc)
    out.mkdir(parents=True, exist_ok=True)
    (out / "hapticbench.json").write_text(json.dumps(doc, indent=1) + "\n")
    (out / "hapticbench.schema.json").write_text(json.dumps(RESULT_SCHEMA, indent=1) + "\n")
    plot(doc, out)
    b = doc["build"]
    text = "\n".join([
        "# hapticbench", "",
        f"`{command}` on the virtual clock (haptic {doc['haptic_hz']:g} Hz), {wall_s / 60:.1f} min"
        f" on {time.strftime('%Y-%m-%d')}; build {b['package_version']} {b['git_commit'] or ''}"
        f"{' (modified)' if b['git_dirty'] else ''}; {doc['machine']['cpu']}, "
        f"{doc['machine']['cpu_count']} cores (shared); seed {doc['seed']}. Result:"
        " hapticbench.json (schema hapticbench.schema.json, version"
        f" {doc['schema_version']}). Cases and references: benchmarks/hapticbench.py.", "",
        *table(doc), "", "The front per case (a method is on it when no other has both a lower"
        " headline error and a lower median cost):", "", *pareto(doc), "",
        *case_paragraphs(doc),
        *stiffness_table(doc), "![hapticbench](hapticbench.png)", "",
    ])  # fmt: skip
    (out / "hapticbench.md").write_text(text)
    return text
