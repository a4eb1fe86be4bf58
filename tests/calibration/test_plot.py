"""The sweep chart is written whole or not at all, with a message naming the file."""

import subprocess
import sys
import textwrap

#: runs plot_sweep under a real file-size limit of 2 kB (the chart is far larger): libpng's writes
#: fail as on a full disk and cv2.imwrite answers False
_FULL_DISK = textwrap.dedent("""
    import resource, signal, sys
    from lfstudio.calibration.plot import plot_sweep
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (2000, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    stats = {"mean": 0.8, "p99": 1.5, "p1": 0.2}
    results = [{"pp_shift_px": r, "trials": 2,
                "without_principal_point": {"residual_px": stats, "true_residual_px": stats}}
               for r in (0.0, 50.0)]
    try:
        plot_sweep(results, sys.argv[1])
    except OSError as exc:
        print(f"{type(exc).__name__}: {exc}")
""")


def test_a_chart_that_cannot_be_written_is_refused_by_name_and_leaves_no_file(tmp_path):
    png = tmp_path / "sweep.png"
    out = subprocess.run([sys.executable, "-c", _FULL_DISK, str(png)], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert "sweep.png: the chart could not be written" in out, out       # not "No such file or directory"
    assert list(tmp_path.iterdir()) == []                                # no half chart, no temporary file
