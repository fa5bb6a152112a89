"""The design page (``scanqa design page``): its HTML and the Plotly figures of a view.

Rendering only: :func:`view_payload` turns a :class:`scanqa.design.rig.RigView` (computed by the
model chain in Python) into Plotly figure dicts and the numbers, and :func:`page_html`
writes the page whose script sends the inputs to the local server and draws what comes
back with plotly.js. The script computes nothing of the model.
"""

from __future__ import annotations

import html
import json
import math

import numpy as np

from scanqa.design.rig import SETTINGS, RigView
from scanqa.numeric import json_ready

_CAM, _PROJ = "#1f77b4", "#9467bd"


def _outline(corners: np.ndarray) -> list[np.ndarray]:
    """x, y, z lists of a closed quadrilateral outline."""
    loop = np.vstack([corners, corners[:1]])
    return [loop[:, i] for i in range(3)]


def _lines(points: np.ndarray, name: str, color: str, dash: str = "solid",
           width: float = 3.0) -> dict:
    return {"type": "scatter3d", "mode": "lines", "name": name, "x": _list(points[0]),
            "y": _list(points[1]), "z": _list(points[2]), "hoverinfo": "name",
            "line": {"color": color, "dash": dash, "width": width}}


def _pyramid_trace(pyr: np.ndarray, name: str, color: str) -> dict:
    """Edges of a view pyramid (apex, then four base corners) as one polyline, NaN-split."""
    apex, base = pyr[0], pyr[1:]
    seg = [np.vstack([apex, c, [np.nan] * 3]) for c in base]
    pts = np.vstack([*seg, base, base[:1]])
    return _lines([pts[:, 0], pts[:, 1], pts[:, 2]], name, color)


def _quad(corners: np.ndarray, name: str, color: str, opacity: float) -> dict:
    return {"type": "mesh3d", "name": name, "showlegend": True, "x": _list(corners[:, 0]),
            "y": _list(corners[:, 1]), "z": _list(corners[:, 2]), "i": [0, 0],
            "j": [1, 2], "k": [2, 3], "color": color, "opacity": opacity, "hoverinfo": "name"}


def _mesh(mesh: tuple[np.ndarray, np.ndarray], name: str, color: str, opacity: float
          ) -> dict:
    """A triangle mesh (vertices (n, 3) [mm], triangles (m, 3)) as a Plotly mesh3d."""
    verts, tris = mesh
    return {"type": "mesh3d", "name": name, "showlegend": True, "x": _list(verts[:, 0]),
            "y": _list(verts[:, 1]), "z": _list(verts[:, 2]), "i": tris[:, 0].tolist(),
            "j": tris[:, 1].tolist(), "k": tris[:, 2].tolist(), "color": color,
            "opacity": opacity, "flatshading": True, "hoverinfo": "name"}


def scene_figure(view: RigView) -> dict:
    """The 3D drawing of Fig. 6: pyramids, focus planes, band, clip planes, volumes."""
    data = [_pyramid_trace(view.camera_pyramid, "Cam (view pyramid)", _CAM),
            _pyramid_trace(view.projector_pyramid, "Proj (view pyramid)", _PROJ),
            _quad(view.camera_focus_plane, "camera focus plane", _CAM, 0.15),
            _quad(view.projector_focus_plane, "projector focus plane", _PROJ, 0.15)]
    for k, plane in enumerate(view.coc_planes):
        trace = _lines(_outline(plane), f"c_c < {view.coc_max_mm * 1e3:g} um band", "red",
                       "dash")
        trace["showlegend"] = k == 0
        trace["legendgroup"] = "coc"
        data.append(trace)
    for k, plane in enumerate(view.clip_planes):
        trace = _lines(_outline(plane), "near / far planes", "blue", "dot", 2.0)
        trace["showlegend"] = k == 0
        trace["legendgroup"] = "clip"
        data.append(trace)
    c = view.axes_crossing
    data.append({"type": "scatter3d", "mode": "markers", "name": "axes crossing",
                 "x": [float(c[0])], "y": [float(c[1])], "z": [float(c[2])],
                 "marker": {"color": "black", "size": 4}})
    data.append(_mesh(view.total_mesh, "total volume", "#f2d024", 0.2))
    usable = f"usable volume (A_c A_p >= {view.level:g}" \
        + (f", c_c <= {view.coc_max_mm:g} mm)" if view.coc_cuts_volume else ")")
    data.append(_mesh(view.usable_mesh, usable, "#d9480f", 0.8))
    layout = {"uirevision": "keep", "margin": {"l": 0, "r": 0, "t": 30, "b": 0},
              "title": {"text": "scanner and reconstruction volumes (Fig. 6)"},
              "legend": {"x": 0, "y": 1},
              "scene": {"aspectmode": "data", "xaxis": {"title": {"text": "X [mm]"}},
                        "yaxis": {"title": {"text": "Y [mm]"}, "autorange": "reversed"},
                        "zaxis": {"title": {"text": "Z [mm]"}},
                        "camera": {"up": {"x": 0, "y": -1, "z": 0},
                                   "eye": {"x": 1.6, "y": -0.9, "z": -0.6}}}}
    return {"data": data, "layout": layout}


def curve_figure(view: RigView) -> dict:
    """The W curve (sigma on the camera axis) over the attenuations, with the usable depth,
    the camera depth of field and the circle-of-confusion band."""
    cv = view.curve
    z, ok = cv["z_mm"], cv["model_valid"]
    combined = cv["attenuation_camera"] * cv["attenuation_projector"]
    valid = cv["sigma_um"][ok & np.isfinite(cv["sigma_um"])]
    top = float(valid.max()) if valid.size else 0.0
    data = [
        _xy(z, np.where(ok, cv["sigma_um"], np.nan), "sigma (model valid) [um]", "black",
            "y"),
        _xy(z, np.where(ok, np.nan, cv["sigma_um"]), "sigma (r > 1/2) [um]", "#999999", "y"),
        _xy(z, cv["attenuation_camera"], "A_c", _CAM, "y2"),
        _xy(z, cv["attenuation_projector"], "A_p", _PROJ, "y2"),
        _xy(z, combined, "A_c A_p", "#d9480f", "y2"),
    ]
    n = view.numbers
    shapes = [_band(n["usable_near_mm"], n["usable_far_mm"], "#d9480f", 0.12),
              _band(view.camera_dof.near_mm, view.camera_dof.far_mm, _CAM, 0.06),
              _vline(n["coc_near_mm"], "red"), _vline(n["coc_far_mm"], "red"),
              {"type": "line", "xref": "paper", "x0": 0, "x1": 1, "yref": "y2",
               "y0": view.level, "y1": view.level, "line": {"dash": "dot", "color": "#d9480f"}}]
    layout = {"margin": {"l": 50, "r": 10, "t": 30, "b": 40}, "uirevision": "keep",
              "title": {"text": "W curve on the camera axis"},
              "xaxis": {"title": {"text": "Z [mm]"}},
              "yaxis": {"title": {"text": "sigma [um]"}, "domain": [0.42, 1.0],
                        "range": [0, 1.5 * top if top > 0 else 1.0]},
              "yaxis2": {"title": {"text": "attenuation [-]"}, "domain": [0, 0.36],
                         "range": [0, 1.02]},
              "legend": {"orientation": "h", "y": -0.2},
              "shapes": [s for s in shapes if s is not None]}
    return {"data": data, "layout": layout}


def _xy(x: np.ndarray, y: np.ndarray, name: str, color: str, axis: str) -> dict:
    return {"type": "scatter", "mode": "lines", "name": name, "x": _list(x), "y": _list(y),
            "yaxis": axis, "line": {"color": color}}


def _band(lo: float, hi: float, color: str, opacity: float) -> dict | None:
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    return {"type": "rect", "xref": "x", "yref": "paper", "x0": lo, "x1": hi, "y0": 0,
            "y1": 1, "fillcolor": color, "opacity": opacity, "line": {"width": 0}}


def _vline(x: float, color: str) -> dict | None:
    if not math.isfinite(x):
        return None
    return {"type": "line", "xref": "x", "yref": "paper", "x0": x, "x1": x, "y0": 0, "y1": 1,
            "line": {"color": color, "dash": "dash", "width": 1}}


def _list(values) -> list:
    """JSON-ready floats: NaN and inf become null (Plotly breaks lines there)."""
    arr = np.round(np.asarray(values, dtype=float), 4)
    finite = np.isfinite(arr)
    if finite.all():
        return arr.tolist()
    return [v if ok else None for v, ok in zip(arr.tolist(), finite.tolist(), strict=True)]


def view_payload(view: RigView, settings: dict) -> dict:
    """Everything one redraw needs: both figures, the numbers, the settings."""
    dof = {"camera_near_mm": view.camera_dof.near_mm, "camera_far_mm": view.camera_dof.far_mm,
           "projector_near_mm": view.projector_dof.near_mm,
           "projector_far_mm": view.projector_dof.far_mm}
    return {"scene": scene_figure(view), "curve": curve_figure(view),
            "numbers": {**view.numbers, "usable_mm3": view.volume.usable_mm3,
                        "total_mm3": view.volume.total_mm3, "step_mm": view.volume.step_mm,
                        **{k: float(v) for k, v in dof.items()}},
            "settings": settings, "coc_cuts_volume": view.coc_cuts_volume}


def dumps_payload(payload: dict) -> str:
    """JSON text; non-finite numbers become null (JSON has no NaN)."""
    return json.dumps(json_ready(payload), allow_nan=False)


#: The numbers panel: payload key, label, unit, decimals.
NUMBERS = (("usable_cm3", "usable volume", "cm^3", 3), ("total_cm3", "total volume", "cm^3", 3),
           ("usable_fraction", "usable / total", "", 4),
           ("usable_depth_mm", "usable depth on the camera axis", "mm", 1),
           ("usable_near_mm", "  from", "mm", 1), ("usable_far_mm", "  to", "mm", 1),
           ("sigma_focus_um", "sigma at camera focus", "um", 2),
           ("sigma_near_um", "sigma at the near end", "um", 2),
           ("sigma_far_um", "sigma at the far end", "um", 2),
           ("camera_near_mm", "camera depth of field from", "mm", 1),
           ("camera_far_mm", "  to", "mm", 1),
           ("projector_near_mm", "projector depth of field from (Z_p)", "mm", 1),
           ("projector_far_mm", "  to", "mm", 1),
           ("coc_near_mm", "c_c band from", "mm", 2), ("coc_far_mm", "  to", "mm", 2))


def _inputs_html(settings: dict) -> str:
    """A slider (snapped to the setting's step) and an exact number box per setting."""
    rows = []
    for key, spec in SETTINGS.items():
        unit = f" [{spec.unit}]" if spec.unit else ""
        rng = f'min="{spec.check.ge:g}" max="{spec.check.le:g}"'  # type: ignore[union-attr]
        value = f'value="{settings[key]:.6g}"'
        rows.append(f'<label>{html.escape(spec.doc)}{html.escape(unit)}<br>'
                    f'<input type="range" id="{key}" data-key="{key}" {rng} '
                    f'step="{spec.step:g}" {value}> '
                    f'<input type="number" id="{key}-n" data-key="{key}" {rng} step="any" '
                    f'{value}></label>')
    return "\n".join(rows)


def _numbers_html() -> str:
    rows = [f'<tr><td>{html.escape(label)}</td><td id="n-{key}" data-decimals="{dec}">'
            f'</td><td>{html.escape(unit)}</td></tr>' for key, label, unit, dec in NUMBERS]
    return "<table id=\"numbers\">" + "".join(rows) + "</table>"


def page_html(settings: dict, title: str) -> str:
    """The design page: inputs, the two figures, the numbers; plotly.js from the server."""
    exact = json.dumps({k: float(v) for k, v in settings.items()}).replace("<", "\\u003c")
    return _PAGE.replace("{{TITLE}}", html.escape(title)) \
        .replace("{{INPUTS}}", _inputs_html(settings)).replace("{{NUMBERS}}", _numbers_html()) \
        .replace("{{SETTINGS}}", exact)


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>scanqa design: {{TITLE}}</title>
<script src="/plotly.min.js"></script>
<style>
body { font-family: sans-serif; margin: 0; display: flex; height: 100vh; }
#side { width: 330px; overflow-y: auto; padding: 8px; font-size: 13px;
        border-right: 1px solid #ccc; }
#side label { display: block; margin-bottom: 6px; }
#side input[type=range] { width: 200px; vertical-align: middle; }
#side input[type=number] { width: 80px; }
#main { flex: 1; display: flex; flex-direction: column; }
#scene { flex: 3; min-height: 300px; }
#curve { flex: 2; min-height: 220px; }
#numbers td { padding: 1px 4px; } #numbers td:nth-child(2) { text-align: right; }
#error { color: #b00; white-space: pre-wrap; }
</style></head>
<body>
<div id="side">
<h3>{{TITLE}}</h3>
{{INPUTS}}
<label><input type="checkbox" id="coc_cuts_volume"> cut the usable volume to the c_c band
(Fig. 6 does not)</label>
<p><button id="export">export config TOML</button>
<label>load config TOML <input type="file" id="load" accept=".toml"></label></p>
<div id="error"></div>
{{NUMBERS}}
<p>redraw: <span id="redraw-ms">-</span> ms (model <span id="model-ms">-</span> ms)</p>
</div>
<div id="main"><div id="scene"></div><div id="curve"></div></div>
<script>
"use strict";
var busy = false, pending = false, redraws = 0;
var JSON_TYPE = {'Content-Type': 'application/json'};
var current = {{SETTINGS}};  // exact values: an input only replaces the one it changes
function settings() { return Object.assign({}, current); }
window.scanqaBusy = function () { return busy || pending; };  // for tests and benchmarks
function setInputs(s) {
  current = Object.assign({}, s);
  Object.keys(s).forEach(function (k) {
    var a = document.getElementById(k), b = document.getElementById(k + '-n');
    if (a) { a.value = s[k]; b.value = Number(s[k]).toPrecision(6); } });
}
function show(numbers) {
  document.querySelectorAll('#numbers td[id]').forEach(function (td) {
    var v = numbers[td.id.slice(2)];
    td.textContent = (v === null || v === undefined) ? 'n/a'
      : Number(v).toFixed(parseInt(td.dataset.decimals, 10)); });
}
function redraw() {
  if (busy) { pending = true; return; }
  busy = true; pending = false;
  var t0 = performance.now();
  var body = JSON.stringify({settings: settings(),
    coc_cuts_volume: document.getElementById('coc_cuts_volume').checked});
  fetch('/api/view', {method: 'POST', headers: JSON_TYPE, body: body}).then(function (r) {
    return r.json().then(function (p) { return {ok: r.ok, p: p}; }); })
  .then(function (res) {
    var p = res.p;
    if (!res.ok) { document.getElementById('error').textContent = p.error; return; }
    document.getElementById('error').textContent = '';
    return Promise.all([Plotly.react('scene', p.scene.data, p.scene.layout),
                        Plotly.react('curve', p.curve.data, p.curve.layout)])
      .then(function () {
        show(p.numbers);
        var ms = performance.now() - t0;
        redraws += 1;
        var el = document.getElementById('redraw-ms');
        el.textContent = ms.toFixed(0); el.dataset.ms = ms; el.dataset.count = redraws;
        document.getElementById('model-ms').textContent = p.model_ms.toFixed(0);
      });
  }).catch(function (e) { document.getElementById('error').textContent = String(e); })
  .finally(function () { busy = false; if (pending) redraw(); });
}
document.querySelectorAll('#side input[data-key]').forEach(function (el) {
  el.addEventListener('input', function () {
    var other = el.type === 'range' ? el.id + '-n' : el.dataset.key;
    document.getElementById(other).value = el.value;
    if (el.type === 'range') { current[el.dataset.key] = parseFloat(el.value); redraw(); } });
  el.addEventListener('change', function () {
    var v = parseFloat(el.value);  // a slider's change follows its input: no second redraw
    if (isFinite(v) && v !== current[el.dataset.key]) { current[el.dataset.key] = v; redraw(); }
  });
});
document.getElementById('coc_cuts_volume').addEventListener('change', redraw);
document.getElementById('export').addEventListener('click', function () {
  fetch('/api/export', {method: 'POST', headers: JSON_TYPE,
                        body: JSON.stringify({settings: settings()})})
  .then(function (r) {  // an error is shown, never saved as scanner.toml
    if (!r.ok) { return r.json().then(function (p) { throw new Error(p.error); }); }
    return r.text(); })
  .then(function (text) {
    document.getElementById('error').textContent = '';
    var a = document.createElement('a');
    a.href = URL.createObjectURL(new Blob([text], {type: 'application/toml'}));
    a.download = 'scanner.toml'; a.click(); })
  .catch(function (e) { document.getElementById('error').textContent = e.message; });
});
document.getElementById('load').addEventListener('change', function (ev) {
  var f = ev.target.files[0]; if (!f) return;
  f.text().then(function (text) {
    return fetch('/api/load', {method: 'POST', headers: JSON_TYPE,
                               body: JSON.stringify({toml: text})}); })
  .then(function (r) { return r.json(); }).then(function (p) {
    if (p.error) { document.getElementById('error').textContent = p.error; return; }
    setInputs(p.settings); redraw(); })
  .catch(function (e) { document.getElementById('error').textContent = String(e); });
});
redraw();
</script>
</body></html>
"""
