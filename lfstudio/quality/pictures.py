"""The quality report's pictures (OpenCV drawing, no Qt): heat maps laid out as the rig's grid, the
disparity map of the centre view in false colour over the image, histograms, and one HTML page that
embeds them all (a single file a lab can attach to a published dataset).

:data:`HEATMAPS` defines the four per-view maps — sharpness, exposure, position error and track
residual — with the value each shows and its colour scale; the GUI's grid overlays use the same
definitions (:func:`heatmap_values`, :func:`heatmap_colour`), so the screen and the report agree.
"""

from __future__ import annotations

import base64
import functools
import html
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np

from lfstudio.dataset.atomic import atomic_write_text, atomic_write_with

_FONT = cv2.FONT_HERSHEY_SIMPLEX
VERDICT_BGR = {"warn": (0, 215, 255), "fail": (40, 40, 230)}
MISSING_BGR = (70, 70, 70)


@dataclass(frozen=True)
class Heatmap:
    key: str
    title: str
    unit: str
    value: Callable[[dict[str, Any]], float | None]     # from one view entry of quality.json
    range: Callable[[dict[str, Any]], tuple[float, float]]  # from the document (thresholds)
    colormap: int            # OpenCV colour map; the scale runs from range[0] to range[1]


def _check_value(name: str, key: str = "value") -> Callable[[dict[str, Any]], float | None]:
    def get(view: dict[str, Any]) -> float | None:
        c = (view.get("checks") or {}).get(name) or {}
        v = c.get(key)
        return float(v) if isinstance(v, (int, float)) else None
    return get


def _exposure_percent(view: dict[str, Any]) -> float | None:
    v = _check_value("exposure")(view)
    return None if v is None else (v - 1.0) * 100.0


def _position_um(view: dict[str, Any]) -> float | None:
    v = _check_value("position")(view)
    return None if v is None else v * 1000.0


HEATMAPS: dict[str, Heatmap] = {h.key: h for h in (
    Heatmap("sharpness", "Sharpness (vs neighbours)", "×", _check_value("sharpness"),
            lambda d: (min(0.5, d["thresholds"]["sharpness_fail"] - 0.1), 1.1), cv2.COLORMAP_INFERNO),
    Heatmap("exposure", "Exposure (vs neighbours)", "%", _exposure_percent,
            lambda d: (-1.5 * 100 * d["thresholds"]["exposure_fail"], 1.5 * 100 * d["thresholds"]["exposure_fail"]),
            cv2.COLORMAP_TWILIGHT_SHIFTED),
    Heatmap("position", "Position error", "µm", _position_um,
            lambda d: (0.0, 1500.0 * d["thresholds"]["position_fail_mm"]), cv2.COLORMAP_INFERNO),
    Heatmap("residual", "Track residual", "px", _check_value("residual"),
            lambda d: (0.0, max(4 * (d.get("tracks", {}).get("typical_view_residual_px") or 0.25), 0.5)),
            cv2.COLORMAP_INFERNO),
)}


def heatmap_values(doc: dict[str, Any], key: str) -> dict[tuple[int, int], float]:
    """Cell → value of heat map ``key`` for every view that has one."""
    h = HEATMAPS[key]
    out = {}
    for v in doc.get("views", []):
        x = h.value(v)
        if x is not None and math.isfinite(x):
            out[(int(v["row"]), int(v["column"]))] = x
    return out


@functools.lru_cache(maxsize=8)
def _lut(colormap: int) -> np.ndarray:
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(-1, 1), colormap).reshape(256, 3)
    lut.setflags(write=False)
    return lut


def heatmap_colour(doc: dict[str, Any], key: str, value: float) -> tuple[int, int, int]:
    """RGB colour of ``value`` on heat map ``key``'s scale."""
    h = HEATMAPS[key]
    lo, hi = h.range(doc)
    t = (value - lo) / (hi - lo) if hi > lo else 0.5
    t = min(max(t, 0.0), 1.0)
    b, g, r = _lut(h.colormap)[int(round(t * 255))]
    return int(r), int(g), int(b)


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.5, colour=(30, 30, 30),
          thick: int = 1) -> None:
    cv2.putText(img, text, org, _FONT, scale, colour, thick, cv2.LINE_AA)


def draw_heatmap(doc: dict[str, Any], key: str, width_px: int = 520) -> np.ndarray:
    """One heat map panel (BGR): the grid coloured by the value, flagged views outlined."""
    h = HEATMAPS[key]
    views = doc.get("views", [])
    rows = max([int(v["row"]) for v in views], default=0) + 1
    cols = max([int(v["column"]) for v in views], default=0) + 1
    grid = doc.get("grid") or {}
    rows, cols = max(rows, int(grid.get("rows", 0))), max(cols, int(grid.get("columns", 0)))
    cell = int(max(3, min(48, (width_px - 40) // max(cols, 1))))
    gw, gh = cols * cell, rows * cell
    top, left, bar_h = 34, 20, 46
    img = np.full((top + gh + bar_h + 10, max(width_px, gw + 2 * left), 3), 255, np.uint8)
    _text(img, h.title, (left, 22), 0.55, (0, 0, 0), 1)
    lo, hi = h.range(doc)
    lut = _lut(h.colormap)
    by_cell = {(int(v["row"]), int(v["column"])): v for v in views}
    for r in range(rows):
        for c in range(cols):
            x0, y0 = left + c * cell, top + r * cell
            v = by_cell.get((r, c))
            val = h.value(v) if v else None
            if val is None:
                colour = MISSING_BGR
            else:
                t = min(max((val - lo) / (hi - lo) if hi > lo else 0.5, 0.0), 1.0)
                colour = tuple(int(x) for x in lut[int(round(t * 255))])
            cv2.rectangle(img, (x0, y0), (x0 + cell - 1, y0 + cell - 1), colour, -1)
            verdict = ((v or {}).get("checks", {}).get(key) or {}).get("verdict")
            if verdict in VERDICT_BGR:
                cv2.rectangle(img, (x0, y0), (x0 + cell - 1, y0 + cell - 1), VERDICT_BGR[verdict],
                              2 if cell >= 10 else 1)
            if v and v.get("status") not in (None, "done"):
                cv2.line(img, (x0, y0), (x0 + cell - 1, y0 + cell - 1), (200, 200, 200), 1)
    # colour bar
    by = top + gh + 12
    bw = min(gw, width_px - 2 * left) if gw > 120 else width_px - 2 * left
    bar = cv2.resize(lut.reshape(1, 256, 3), (bw, 12), interpolation=cv2.INTER_LINEAR)
    img[by:by + 12, left:left + bw] = bar
    fmt = (lambda x: f"{x:.0f}") if abs(hi - lo) >= 10 else (lambda x: f"{x:.2f}")
    _text(img, f"{fmt(lo)} {h.unit}", (left, by + 30), 0.45)
    label = f"{fmt(hi)} {h.unit}"
    _text(img, label, (left + bw - 9 * len(label), by + 30), 0.45)
    return img


def heatmaps_sheet(doc: dict[str, Any]) -> np.ndarray:
    """The four heat maps, two by two, with a legend line."""
    panels = [draw_heatmap(doc, k) for k in HEATMAPS]
    w = max(p.shape[1] for p in panels)
    panels = [cv2.copyMakeBorder(p, 0, 0, 0, w - p.shape[1], cv2.BORDER_CONSTANT, value=(255, 255, 255))
              for p in panels]
    hmax = max(p.shape[0] for p in panels)
    panels = [cv2.copyMakeBorder(p, 0, hmax - p.shape[0], 0, 0, cv2.BORDER_CONSTANT, value=(255, 255, 255))
              for p in panels]
    sheet = np.vstack([np.hstack(panels[:2]), np.hstack(panels[2:])])
    legend = np.full((30, sheet.shape[1], 3), 255, np.uint8)
    x = 20
    for name, colour in (("warn", VERDICT_BGR["warn"]), ("fail", VERDICT_BGR["fail"]), ("no value", MISSING_BGR)):
        cv2.rectangle(legend, (x, 8), (x + 14, 22), colour, 2 if name != "no value" else -1)
        _text(legend, name, (x + 20, 21), 0.45)
        x += 110
    _text(legend, "outline: the view's verdict on that check", (x + 10, 21), 0.45, (90, 90, 90))
    return np.vstack([sheet, legend])


LABEL_SCALE = 0.42
COLOUR_BAR_TICKS = (0.0, 0.25, 0.5, 0.75, 1.0)
LABEL_GAP_PX = 8


TICK_END_PX = 26                 # the colour bar's ticks end this far under the picture
LABEL_GAP_BELOW_TICK_PX = 5      # white between a tick and its label (a label touching it read as crossed out)


def _text_width_px(text: str, scale: float = LABEL_SCALE) -> int:
    return cv2.getTextSize(text, _FONT, scale, 1)[0][0]


def _text_height_px(scale: float = LABEL_SCALE) -> int:
    """Height of a label's digits above its baseline."""
    return cv2.getTextSize("0.0 px", _FONT, scale, 1)[0][1]


def colour_bar_labels(lo: float, hi: float, bar_width_px: int, width_px: int,
                      depth_scale_m_px: float | None = None,
                      ) -> list[tuple[int, list[tuple[str, int]]]]:
    """The disparity colour bar's ticks that fit: ``(x, [(text, left_x), ...])`` for each, the value in
    px on the first line and, with ``depth_scale_m_px``, the depth in metres on a second line. Labels
    are centred on their tick, kept inside the picture and never overlap: the two ends are always
    labelled, an inner tick whose label would touch a neighbour's is left out."""
    ticks = []
    for frac in sorted(COLOUR_BAR_TICKS, key=lambda f: (f not in (0.0, 1.0), abs(f - 0.5))):  # ends first
        val = lo + frac * (hi - lo)
        texts = [f"{val:.2f} px"]
        if depth_scale_m_px:
            texts.append(f"{depth_scale_m_px / val:.2f} m" if val > 0 else "")
        x = int(20 + frac * (bar_width_px - 1))
        lines = []
        for text in texts:
            tw = _text_width_px(text)
            lines.append((text, min(max(2, x - tw // 2), width_px - 2 - tw)))
        span = (min(left for _, left in lines),
                max(left + _text_width_px(text) for text, left in lines))
        if any(span[0] < other[1] + LABEL_GAP_PX and other[0] < span[1] + LABEL_GAP_PX
               for other, _ in ticks):
            continue
        ticks.append((span, (x, [(t, left) for t, left in lines if t])))
    return sorted((tick for _, tick in ticks), key=lambda tick: tick[0])


def colour_range(disparity_px: np.ndarray, range_px: tuple[float, float] | None = None) -> tuple[float, float]:
    """The disparities the colours of :func:`disparity_picture` span: ``range_px``, else the 1st to 99th
    percentile of the finite values."""
    fin = disparity_px[np.isfinite(disparity_px)]
    if range_px is None:
        lo, hi = (float(np.percentile(fin, 1)), float(np.percentile(fin, 99))) if fin.size else (0.0, 1.0)
    else:
        lo, hi = range_px
    return (lo, hi) if hi > lo else (lo, lo + 1e-3)


def disparity_picture(disparity_px: np.ndarray, image8: np.ndarray, depth_note: str = "",
                      range_px: tuple[float, float] | None = None, depth_scale_m_px: float | None = None,
                      colour_bar: bool = True) -> np.ndarray:
    """False-colour disparity (TURBO: near = red) over the grey image, with a colour bar in px and,
    with ``depth_scale_m_px`` (depth = scale / disparity), in metres (``colour_bar`` False: the
    picture alone, for a window that draws its bar at screen resolution: :func:`colour_range`)."""
    d = disparity_px
    lo, hi = colour_range(d, range_px)
    t = np.clip((np.nan_to_num(d, nan=lo) - lo) / (hi - lo), 0, 1)
    colour = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    grey = cv2.cvtColor(image8, cv2.COLOR_GRAY2BGR)
    out = cv2.addWeighted(colour, 0.65, grey, 0.35, 0)
    out[~np.isfinite(d)] = (grey[~np.isfinite(d)] * 0.5).astype(np.uint8)
    if not colour_bar:
        return out
    h, w = out.shape[:2]
    bar_h = 60 + (14 if depth_scale_m_px else 0)
    canvas = np.full((h + bar_h, w, 3), 255, np.uint8)
    canvas[:h] = out
    bw = max(w - 40, 1)      # a view narrower than the margins still gets a (tiny) bar
    bar = cv2.applyColorMap(np.linspace(0, 255, bw).astype(np.uint8).reshape(1, -1), cv2.COLORMAP_TURBO)
    canvas[h + 8:h + 22, 20:20 + bw] = cv2.resize(bar, (bw, 14), interpolation=cv2.INTER_NEAREST)
    for frac in COLOUR_BAR_TICKS:
        x = int(20 + frac * (bw - 1))
        cv2.line(canvas, (x, h + 22), (x, h + TICK_END_PX), (0, 0, 0), 1)
    label_baseline = h + TICK_END_PX + LABEL_GAP_BELOW_TICK_PX + _text_height_px()
    for _, lines in colour_bar_labels(lo, hi, bw, w, depth_scale_m_px):
        for i, (text, left) in enumerate(lines):
            _text(canvas, text, (left, label_baseline + 14 * i), LABEL_SCALE)
    if depth_note:
        _text(canvas, depth_note, (20, h + bar_h - 2), 0.4, (90, 90, 90))
    return canvas


def bar_chart(counts: list[int], edges: list[float], *, title: str, x_label: str,
              marks: Sequence[tuple[float, str, tuple[int, int, int]]] = (), size_px: tuple[int, int] = (640, 300)
              ) -> np.ndarray:
    """A histogram (BGR) with labelled vertical marks."""
    w, h = size_px
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 50, 20, 40, 50
    x0, x1 = float(edges[0]), float(edges[-1])
    top_count = max(max(counts, default=0), 1)

    def px(x: float) -> int:
        return int(round(left + (x - x0) / max(x1 - x0, 1e-12) * (w - left - right)))

    for c, a, b in zip(counts, edges[:-1], edges[1:]):
        y = int(round(h - bottom - c / top_count * (h - top - bottom)))
        cv2.rectangle(img, (px(a), y), (max(px(a), px(b) - 1), h - bottom), (180, 130, 60), -1)
    cv2.rectangle(img, (left, top), (w - right, h - bottom), (0, 0, 0), 1)
    for k in range(5):
        x = x0 + k * (x1 - x0) / 4
        _text(img, f"{x:.2f}", (px(x) - 14, h - bottom + 18), 0.4)
    for i, (x, label, colour) in enumerate(marks):
        if x0 <= x <= x1:
            cv2.line(img, (px(x), top), (px(x), h - bottom), colour, 2, cv2.LINE_AA)
            _text(img, label, (min(px(x) + 4, w - 8 * len(label)), top + 14 + 14 * i), 0.4, colour)
    _text(img, title, (left, 25), 0.55, (0, 0, 0))
    _text(img, x_label, (left, h - 12), 0.45)
    return img


def scatter_errors(doc: dict[str, Any], size_px: int = 300) -> np.ndarray:
    """Measured position errors (dx, dy) of every view with the warn/fail circles."""
    img = np.full((size_px + 50, size_px + 20, 3), 255, np.uint8)
    t = doc["thresholds"]
    lim = 1.3 * t["position_fail_mm"]
    c0 = (10 + size_px // 2, 40 + size_px // 2)
    scale = (size_px / 2) / lim
    cv2.rectangle(img, (10, 40), (10 + size_px, 40 + size_px), (0, 0, 0), 1)
    cv2.line(img, (c0[0], 40), (c0[0], 40 + size_px), (220, 220, 220), 1)
    cv2.line(img, (10, c0[1]), (10 + size_px, c0[1]), (220, 220, 220), 1)
    for r_mm, colour in ((t["position_warn_mm"], VERDICT_BGR["warn"]), (t["position_fail_mm"], VERDICT_BGR["fail"])):
        cv2.circle(img, c0, int(round(r_mm * scale)), colour, 1, cv2.LINE_AA)
    for v in doc.get("views", []):
        e = ((v.get("checks") or {}).get("position") or {}).get("error_mm")
        if not e:
            continue
        x = int(round(c0[0] + max(-lim, min(lim, e[0])) * scale))
        y = int(round(c0[1] + max(-lim, min(lim, e[1])) * scale))
        colour = VERDICT_BGR.get(v["checks"]["position"]["verdict"], (60, 60, 60))
        cv2.circle(img, (x, y), 3, colour, -1, cv2.LINE_AA)
    _text(img, "Position errors (dx, dy)", (10, 18), 0.5, (0, 0, 0))
    _text(img, f"box: +/-{lim:.2f} mm", (10, 34), 0.4, (90, 90, 90))
    return img


def _write_png(path: Path, img: np.ndarray) -> Path:
    def write(tmp: Path) -> None:
        if not cv2.imwrite(str(tmp), img):
            raise OSError(f"{path}: cannot write the picture")
    return atomic_write_with(path, write)


def write_pictures(folder: Path, report, dataset) -> dict[str, Path]:
    """Write heatmaps.png, disparity.png (+ disparity.npy), histograms.png and report.html."""
    doc = report.document
    doc.setdefault("grid", {"columns": dataset.grid.columns, "rows": dataset.grid.rows})
    folder.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {"heatmaps": _write_png(folder / "heatmaps.png", heatmaps_sheet(doc))}
    depth = doc.get("depth_range") or {}
    charts = []
    if depth.get("histogram"):
        marks = []
        if depth.get("export_disp_min_px") is not None:
            lo, hi = depth["export_disp_min_px"], depth["export_disp_max_px"]
            marks += [(lo, f"planned far {lo:.2f}", (40, 140, 40)), (hi, f"planned near {hi:.2f}", (40, 140, 40))]
        marks += [(depth["disparity_min_px"], "measured far", (40, 40, 200)),
                  (depth["disparity_max_px"], "measured near", (40, 40, 200))]
        charts.append(bar_chart(depth["histogram"]["counts"], depth["histogram"]["edges_px"],
                                title="Neighbour disparity of the tracked points",
                                x_label="px between horizontal neighbours (full resolution)", marks=marks))
    charts.append(scatter_errors(doc))
    hmax = max(c.shape[0] for c in charts)
    charts = [cv2.copyMakeBorder(c, 0, hmax - c.shape[0], 0, 10, cv2.BORDER_CONSTANT, value=(255, 255, 255))
              for c in charts]
    out["histograms"] = _write_png(folder / "histograms.png", np.hstack(charts))
    if report.disparity is not None:
        d = report.disparity
        disp_doc = doc.get("disparity_map") or {}
        note = (f"view {disp_doc['view']}; " if disp_doc else "") + \
            (f"px between horizontal neighbours, {disp_doc['reference']}; " if disp_doc.get("reference") else "") + \
            ("rectified with calibration.json" if doc["calibration"]["used"] else "not rectified (no calibration)")
        out["disparity"] = _write_png(folder / "disparity.png", disparity_picture(
            d.disparity_px, d.image8, note, depth_scale_m_px=report.depth_scale_m_px))
        out["disparity_data"] = atomic_write_with(folder / "disparity.npy",
                                                  lambda p: np.save(p, d.disparity_px.astype(np.float16)))
    out["report"] = write_html(folder / "report.html", doc, {k: p for k, p in out.items() if p.suffix == ".png"})
    return out


def write_html(path: Path, doc: dict[str, Any], pictures: dict[str, Path]) -> Path:
    """One self-contained page: the summary, the dataset checks, the pictures and the flagged views."""
    from lfstudio.dataset.zero_plane import DISPARITY_DEFINITION
    from lfstudio.quality.summaries import disparity_map_summary, disparity_summary, repeatability_summary

    def img(key: str, alt: str) -> str:
        p = pictures.get(key)
        if p is None or not Path(p).is_file():
            return ""
        data = base64.b64encode(Path(p).read_bytes()).decode("ascii")
        return f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}"><figcaption>' \
               f"{html.escape(alt)}</figcaption></figure>"

    s = doc["summary"]
    rep = doc.get("repeatability") or {}
    depth = doc.get("depth_range") or {}
    rows = "".join(
        f"<tr class='{v['verdict']}'><td>{html.escape(v['view'])}</td><td>{v['verdict']}</td>"
        f"<td>{'<br>'.join(html.escape(r) for r in v.get('reasons', []))}</td></tr>"
        for v in doc["views"] if v["verdict"] in ("warn", "fail"))
    body = f"""<!doctype html><html><head><meta charset="utf-8"><title>Quality report — {html.escape(doc['dataset'])}</title>
<style>body{{font-family:sans-serif;margin:2em;color:#222}} table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:4px 8px;vertical-align:top}} tr.fail td{{background:#fde2e2}}
tr.warn td{{background:#fff1d6}} figure{{display:inline-block;margin:0 1em 1em 0}} img{{max-width:100%}}
.verdict{{font-size:1.4em;font-weight:bold}}</style></head><body>
<h1>Dataset quality report</h1>
<p>{html.escape(doc['dataset'])}<br>checked {html.escape(doc['created'])} by lfstudio</p>
<p class="verdict">Verdict: {doc['verdict']}</p>
<table><tr><th>views</th><th>pass</th><th>warn</th><th>fail</th></tr>
<tr><td>{s['views']}</td><td>{s['pass']}</td><td>{s['warn']}</td><td>{s['fail']}</td></tr></table>
<h2>Dataset</h2><table>
<tr><td>measured repeatability</td><td>{html.escape(repeatability_summary(rep))}</td></tr>
<tr><td>scene depth</td><td>{html.escape(str(depth.get('why', '–')))}</td></tr>
<tr><td>neighbour disparity</td><td>{html.escape(disparity_summary(depth))}</td></tr>
<tr><td>disparity map</td><td>{html.escape(disparity_map_summary(doc['disparity_map'], depth)) if doc.get('disparity_map') else '–'}</td></tr>
<tr><td>disparity means</td><td>{html.escape(DISPARITY_DEFINITION)}</td></tr>
<tr><td>calibration</td><td>{'used' if doc['calibration']['used'] else html.escape(doc['calibration']['note'] or '')}</td></tr>
</table>
<h2>Heat maps</h2>{img('heatmaps', 'Per-view checks laid out as the rig grid')}
<h2>Disparity</h2>{img('disparity', 'Disparity map of the centre view (near = red)')}
{img('histograms', 'Neighbour disparity of the tracks; position errors')}
<h2>Flagged views</h2>{'<table><tr><th>view</th><th>verdict</th><th>why</th></tr>' + rows + '</table>' if rows else '<p>none</p>'}
<p>Thresholds and the meaning of each check: docs/quality.md of lfstudio.</p>
</body></html>
"""
    return atomic_write_text(path, body)
