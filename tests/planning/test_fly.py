"""The fly-scan planner: the fastest row speed within every limit, which limit binds, and refusals
with the numbers (lfstudio.planning.fly; `lfstudio plan`'s Fly scanning section and --fly)."""

import json
import math
import subprocess
import sys

import pytest

from lfstudio.planning.fly import MIN_FLY_SPEED_MM_S, FlyInputs, fly_inputs_of, plan_fly, row_time_s
from lfstudio.planning.presets import reference_plan


def fast_camera(**kw):
    return reference_plan().replace(**{"exposure_s": 0.001, "frame_rate_fps": 20.0, "transfer_s": 0.05, **kw})


def test_blur_limit_sets_the_speed_from_the_near_distance():
    # one pixel at 1.77 m with 50 mm and 4.53 µm covers 160 µm: 0.5 px in 1 ms allows 80.2 mm/s
    r = plan_fly(fly_inputs_of(fast_camera(frame_rate_fps=100.0, report_rate_hz=None)))
    assert r.possible and r.binding == "blur"
    assert r.speed_mm_s == pytest.approx(0.5 * 1770 * 4.53e-3 / 50 / 0.001)
    assert r.blur_px == pytest.approx(0.5)


def test_camera_frame_rate_binds_and_the_time_adds_up():
    plan = fast_camera(frame_rate_fps=10.0)
    r = plan_fly(fly_inputs_of(plan))
    assert r.binding == "camera frame rate" and r.speed_mm_s == pytest.approx(40.0)
    assert r.frame_interval_s == pytest.approx(0.1)
    assert r.blur_px < 0.5
    row = row_time_s(400.0, 40.0, 500.0)
    assert r.time_s > 21 * row and r.time_s < 21 * row + 20 * 1.0 + 1.0
    # faster than the step scan with the same camera
    assert r.time_s < plan.derive().capture_time_s


def test_bandwidth_reports_axis_and_run_up_limits():
    base = FlyInputs(columns=11, rows=2, spacing_mm=(4.0, 6.0), exposure_s=1e-4, near_mm=1770, focal_length_mm=50,
                     pixel_pitch_um=4.53, frame_rate_fps=1000.0, travel_mm=4000)
    assert plan_fly(base).binding == "axis speed"
    r = plan_fly(FlyInputs(**{**base.__dict__, "bandwidth_mb_s": 100.0, "bytes_per_frame": 10_000_000}))
    assert r.binding == "camera bandwidth" and r.speed_mm_s == pytest.approx(40.0)
    r = plan_fly(FlyInputs(**{**base.__dict__, "report_rate_hz": 5.0}))
    assert r.binding == "position reports" and r.speed_mm_s == pytest.approx(20.0)
    r = plan_fly(FlyInputs(**{**base.__dict__, "travel_mm": 40.5}))      # 0.5 mm beside a 40 mm row
    assert r.binding == "run-up room" and r.run_up_mm * 2 == pytest.approx(0.5)


def test_a_blur_limit_no_speed_meets_is_refused_with_the_numbers():
    r = plan_fly(fly_inputs_of(reference_plan()))          # 0.5 s exposure: 0.16 mm/s
    assert not r.possible and r.binding == "blur"
    assert "0.16 mm/s" in r.refusal and "500 ms" in r.refusal and str(MIN_FLY_SPEED_MM_S) in r.refusal


def test_a_too_slow_camera_and_a_too_fast_asked_speed_are_refused():
    r = plan_fly(fly_inputs_of(fast_camera(frame_rate_fps=0.1)))
    assert not r.possible and r.binding == "camera frame rate" and "0.1 frames/s" in r.refusal
    r = plan_fly(fly_inputs_of(fast_camera(fly_speed_mm_s=150.0)))
    assert not r.possible and "150 mm/s" in r.refusal and "80" in r.refusal
    r = plan_fly(fly_inputs_of(fast_camera(report_rate_hz=0.05)))
    assert not r.possible and r.binding == "position reports" and "0.05 position reports/s" in r.refusal
    r = plan_fly(fly_inputs_of(fast_camera(fly_speed_mm_s=30.0)))
    assert r.possible and r.speed_mm_s == 30.0 and r.binding == "asked for"


def test_a_bracket_is_refused():
    r = plan_fly(fly_inputs_of(fast_camera(bracket="-1,0,1")))
    assert not r.possible and "bracket" in r.refusal


def _plan(*args):
    return subprocess.run([sys.executable, "-m", "lfstudio", "plan", *args], capture_output=True, text=True,
                          timeout=120)


def test_cli_prints_step_and_fly_times_and_the_binding_limit():
    out = _plan("--exposure-s", "0.001", "--frame-rate-fps", "20", "--transfer-s", "0.05")
    assert out.returncode == 0, out.stderr
    assert "Fly scanning" in out.stdout and "camera frame rate binds" in out.stdout
    assert "step scan" in out.stdout and "fly scan" in out.stdout
    j = _plan("--exposure-s", "0.001", "--frame-rate-fps", "20", "--transfer-s", "0.05", "--json")
    fly = json.loads(j.stdout)["fly"]
    assert fly["possible"] and math.isclose(fly["speed_mm_s"], 80.0)


def test_cli_fly_refusal_is_one_line_exit_2():
    out = _plan("--fly")
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and "--fly" in out.stderr and "0.16 mm/s" in out.stderr
    assert "Traceback" not in out.stderr
