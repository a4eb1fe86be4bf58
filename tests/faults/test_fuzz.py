"""Fault matrix, hostile files: Hypothesis mutates the manifest, processing profiles, scene plans and rig
profiles (NaN, infinities, huge and negative numbers, wrong types, deep nesting, bytes that are not
UTF-8); every stage that reads them either works or refuses with an operator's error (LfError: one
line in the CLI), never another exception (a traceback)."""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lfstudio.dataset import Dataset
from lfstudio.errors import LfError

#: examples per fuzz test (LFSTUDIO_FUZZ_EXAMPLES=1500 for a longer hunt outside CI)
FUZZ = settings(max_examples=int(os.environ.get("LFSTUDIO_FUZZ_EXAMPLES", 60)), deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

HOSTILE = st.one_of(
    st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1e300, 10 ** 30, -(10 ** 30), -3, -1.5, 0, 0.0, True,
                     None, "", "x", "../outside", "/etc/passwd", [], {}, [1, 2, 3], {"get": 1}, 2.5]),
    st.integers(), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
    st.recursive(st.none() | st.integers() | st.floats(), lambda children: st.lists(children, max_size=3) |
                 st.dictionaries(st.text(max_size=5), children, max_size=3), max_leaves=8),
)


def paths_of(value, prefix=()):
    """Every path into a JSON value (dict keys and list indexes), the value's own first."""
    out = [prefix]
    if isinstance(value, dict):
        for k, v in value.items():
            out += paths_of(v, prefix + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value[:3]):
            out += paths_of(v, prefix + (i,))
    return out


def mutate(doc, path, value, delete=False):
    doc = json.loads(json.dumps(doc))
    if not path:
        return value
    target = doc
    for key in path[:-1]:
        target = target[key]
    if delete and isinstance(target, dict):
        target.pop(path[-1], None)
    else:
        target[path[-1]] = value
    return doc


def deep(n: int) -> str:
    return "[" * n + "]" * n


# -- the manifest ----------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fuzz_dataset(tmp_path_factory):
    """A 3 x 2 dataset scanned with the instant devices (tiny PNG views), processed once and with an
    export profile: every stage has something to read."""
    from lfstudio.rig.profile import load_rig
    from lfstudio.scan.engine import ScanEngine
    from lfstudio.scan.scan_plan import ScanPlan
    from lfstudio.studio.devices import open_studio
    from lfstudio.studio.session import create_scan_dataset

    rig = load_rig()
    plan = ScanPlan.centered(3, 2, (4.0, 6.0), rig, settle_s=0.0)
    studio = open_studio("instant", "instant", rig, time_scale=0.0, view_region_mm=plan.extent_mm())
    root = tmp_path_factory.mktemp("fuzz") / "ds"
    ds = create_scan_dataset(root, plan, rig={"name": rig.name}, camera={"name": "instant", "sensor_px": [64, 48],
                                                                         "pixel_pitch_um": 4.0},
                             lens={"name": "test", "focal_length_mm": 50.0})
    engine = ScanEngine(ds, plan, studio.rig, studio.camera, time_scale=0.0)
    engine.start()
    engine.wait(60)
    studio.close()
    ds.close()
    (root / "processing.toml").write_text("[rectify]\nenabled = false\n[deflicker]\nsize_px = 16\n")
    return root


def run_stages(root: Path, tmp: Path) -> None:
    """What info, process, export and calibrate do with a dataset, in this process; LfError is the
    refusal an operator reads, anything else fails the test."""
    from lfstudio.calibration.calibrate import calibrate_dataset
    from lfstudio.calibration.model import load_calibration
    from lfstudio.export import ExportOptions, estimate_export, export_dataset
    from lfstudio.processing.pipeline import process_dataset
    from lfstudio.dataset.profile import Profile

    try:
        ds = Dataset.open(root)
    except LfError:
        return
    ds.summary()
    ds.verify_files()
    for stage in ("export", "process", "calibrate"):
        try:
            if stage == "export":
                options = ExportOptions(format="png", out=tmp / "export", overwrite=True)
                estimate_export(ds, options)
                export_dataset(ds, options)
            elif stage == "process":
                process_dataset(ds, Profile.for_dataset(root), workers=0, force=True)
            else:
                load_calibration(ds)
                calibrate_dataset(ds, "2x2", focal_length_px=100.0)
        except LfError:
            pass
        finally:
            ds.close()


@FUZZ
@given(data=st.data())
def test_a_mutated_manifest_is_refused_or_works_in_every_stage(fuzz_dataset, tmp_path, data):
    base = json.loads((fuzz_dataset / "dataset.json").read_text())
    path = data.draw(st.sampled_from(paths_of(base)), label="path")
    value = data.draw(HOSTILE, label="value")
    delete = data.draw(st.booleans(), label="delete")
    root = tmp_path / "ds"
    if root.exists():
        shutil.rmtree(root)
    shutil.copytree(fuzz_dataset, root)
    (root / "dataset.json").write_text(json.dumps(mutate(base, path, value, delete)))   # NaN/Infinity written as is
    run_stages(root, tmp_path)


@pytest.mark.parametrize("text", [deep(100_000), '{"format": ' + deep(5000) + "}", "\ufeff{}", "{]", "",
                                  '{"views": NaN}', "1e999999"])
def test_a_manifest_that_is_not_json_of_a_dataset_is_one_error(fuzz_dataset, tmp_path, text):
    root = tmp_path / "ds"
    shutil.copytree(fuzz_dataset, root)
    (root / "dataset.json").write_text(text)
    with pytest.raises(LfError):
        Dataset.open(root)


# -- processing profiles, scene plans, rig profiles ------------------------------------------------------------------
@FUZZ
@given(data=st.data())
def test_a_mutated_processing_profile_is_refused_or_valid(data):
    import tomli_w

    from lfstudio.dataset.profile import Profile

    base = Profile().to_dict()
    path = data.draw(st.sampled_from([p for p in paths_of(base) if p]), label="path")
    value = data.draw(HOSTILE.filter(lambda v: v is not None), label="value")
    try:
        text = tomli_w.dumps(mutate(base, path, value))
    except (TypeError, ValueError):                      # not expressible in TOML: write it by hand
        text = f"[{path[0]}]\n{path[-1]} = {value!r}\n".replace("nan", "nan").replace("'", '"')
    try:
        profile = Profile.from_toml(text, "p.toml")
    except LfError:
        return
    profile.validate()
    json.dumps(profile.to_dict(), allow_nan=False)       # what is accepted can be saved


@FUZZ
@given(st.binary(max_size=200))
def test_a_profile_or_plan_file_of_any_bytes_is_one_error(tmp_path, raw):
    from lfstudio.planning.scene_plan import load_plan
    from lfstudio.dataset.profile import Profile

    path = tmp_path / "f.toml"
    path.write_bytes(raw)
    for load in (Profile.load, load_plan):
        try:
            load(path)
        except LfError:
            pass


@FUZZ
@given(data=st.data())
def test_a_mutated_scene_plan_is_refused_or_plans(tmp_path, data):
    from lfstudio.planning.presets import reference_plan
    from lfstudio.planning.scene_plan import load_plan

    base = reference_plan().to_dict()
    path = data.draw(st.sampled_from([p for p in paths_of(base) if p]), label="path")
    value = data.draw(HOSTILE, label="value")
    plan_file = tmp_path / "plan.json"
    plan_file.write_text(json.dumps(mutate(base, path, value)))
    try:
        plan = load_plan(plan_file)
        plan.derive()
    except LfError:
        pass


@FUZZ
@given(data=st.data())
def test_a_mutated_rig_profile_is_refused_or_keeps_targets_in_the_travel(data):
    from lfstudio.resources import load_presets
    from lfstudio.rig.motion import SoftLimitError, check_target
    from lfstudio.rig.profile import rig_from_dict

    base = load_presets("rigs")["Reference gantry"]
    path = data.draw(st.sampled_from([p for p in paths_of(base) if p]), label="path")
    value = data.draw(HOSTILE, label="value")
    try:
        rig = rig_from_dict("Fuzz", mutate(base, path, value))
    except LfError:
        return
    for axis in (rig.horizontal, rig.vertical):
        assert 0 <= axis.soft_min_mm < axis.soft_max_mm <= axis.travel_mm
    with pytest.raises(SoftLimitError):
        check_target(rig, 5000, -40)                     # the move: never sent


# -- a controller's $$ and $# answers ---------------------------------------------------------------------------------
def _hostile_grbl():
    from lfstudio.sim.grbl_controller import GrblSimulator

    class HostileGrbl(GrblSimulator):
        """Our GRBL simulator, whose ``$$`` and ``$#`` answers carry extra lines the test chooses
        (malformed settings and parameters, huge codes, noise) before the real ones."""

        extra: dict[str, list[str]] = {"$$": [], "$#": []}

        def _system(self, line):
            out = super()._system(line)
            if out is not None and line in self.extra:
                out = "".join(f"{text}\r\n" for text in self.extra[line]).encode("utf-8", "replace") + out
            return out
    return HostileGrbl


answer_lines = st.one_of(
    st.builds(lambda k, v: f"${k}={v}", st.integers(-5, 10 ** 6), st.text("0123456789.-+enaif", max_size=12)),
    st.builds(lambda n, v: f"[{n}:{v}]", st.sampled_from(["G54", "G55", "G92", "G28", "PRB", "TLO", "VER", "OPT"]),
              st.text("0123456789.,-:e", max_size=30)),
    st.builds(lambda d: f"ALARM:{d}", st.text("0123456789", min_size=5, max_size=5000)),
    st.text(st.characters(blacklist_characters="\r\n", blacklist_categories=("Cs",)), max_size=60),
).filter(lambda text: text.strip() not in ("ok",) and not text.strip().startswith(("error:", "<", "Grbl")))


@settings(max_examples=25, deadline=None)
@given(settings_lines=st.lists(answer_lines, max_size=4), param_lines=st.lists(answer_lines, max_size=4))
def test_connect_survives_hostile_settings_and_parameter_answers(settings_lines, param_lines):
    from lfstudio.rig.grbl import GrblController
    from lfstudio.rig.profile import load_rig

    rig = load_rig()
    sim = _hostile_grbl()(rig, time_scale=0.0, seed=1)
    sim.extra = {"$$": settings_lines, "$#": param_lines}
    port = sim.start()
    controller = GrblController(port, rig, timeout_s=1.0)
    try:
        controller.connect()                     # refused (DeviceError) or connected, never another exception
        status = controller.status()
        assert status.position_mm is None or all(math.isfinite(v) for v in status.position_mm)
    except LfError:
        pass
    finally:
        controller.disconnect()
        sim.close()


DEEP_TOML = "x = " + "[" * 3000 + "]" * 3000 + "\n"     # tomllib recurses once per level


@pytest.mark.parametrize("what", ["journal line", "plan", "processing profile", "rig preset"])
def test_nesting_a_thousand_deep_is_one_line_not_a_recursion_error(what, scanned, tmp_path, run_cli):
    from tests.faults.conftest import assert_one_line_error

    root = scanned(3, 2)
    env = {}
    if what == "journal line":
        (root / "journal.jsonl").write_text('{"seq": 99, "row": 0, "column": 0, "set": ' + "[" * 3000 + "]" * 3000
                                            + "}\n")
        proc = run_cli("info", root)
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr    # the line is ignored
        assert "unreadable record ignored" in proc.stdout + proc.stderr
        return
    if what == "plan":
        (tmp_path / "plan.toml").write_text(DEEP_TOML)
        args = ("scan", "--port", "instant", "--camera", "instant", "--plan", tmp_path / "plan.toml",
                "--out", tmp_path / "new")
    elif what == "processing profile":
        (tmp_path / "p.toml").write_text(DEEP_TOML)
        args = ("process", root, "--workers", "0", "--profile", tmp_path / "p.toml")
    else:
        (tmp_path / "config" / "presets").mkdir(parents=True)
        (tmp_path / "config" / "presets" / "rigs.toml").write_text(DEEP_TOML)
        env = {"LFSTUDIO_CONFIG_DIR": str(tmp_path / "config")}
        args = ("scan", "--port", "instant", "--camera", "instant", "--grid", "2x1", "--out", tmp_path / "new")
    proc = run_cli(*args, env=env)
    assert "RecursionError" not in proc.stderr
    assert_one_line_error(proc, proc.returncode if proc.returncode in (1, 2) else 2, "nested too deeply")
