"""Report of a calibration from board poses: per-pose reprojection RMS (flagged poses),
the poses left out in turn, and the comparison with a reference calibration."""

from __future__ import annotations

import numpy as np

from scanqa.calibration.board_fit import FLAG_FACTOR, BoardCalibration
from scanqa.numeric import json_ready
from scanqa.report.html import Page
from scanqa.report.plots import new_figure


def summary(result: BoardCalibration) -> dict:
    """JSON-ready summary of a board calibration."""
    data = result.data
    return {
        "format": "scanqa-board-calibration-report/1",
        "model": result.model,
        "corner_method": result.corner_method,
        "errors_px": dict(data.errors),
        "camera_matrix": np.asarray(data.Kc).tolist(),
        "camera_distortion": np.asarray(data.kc).tolist(),
        "projector_matrix": np.asarray(data.Kp).tolist(),
        "projector_distortion": np.asarray(data.kp).tolist(),
        "rotation": np.asarray(data.Rp).tolist(),
        "translation_mm": np.asarray(data.Tp).tolist(),
        "poses": [p.as_dict() for p in result.poses],
        "flagged_poses": result.flagged,
        "flag_rule": f"pose RMS > {FLAG_FACTOR:g} x the median of the other poses",
        "parameter_std": result.parameter_std,
        "parameter_std_fit": dict(result.fit_std),
        "parameter_std_jackknife": result.jackknife_std,
        "joint_fit": {"noise_px": result.bundle.get("noise_px", {}),
                      "model_terms": result.bundle.get("model_terms", {})},
        "held_out": list(result.held_out),
        "comparison": dict(result.comparison),
        "board_flatness": json_ready(dict(result.flatness)),  # JSON has no NaN
    }


def render(result: BoardCalibration) -> str:
    """The board calibration report as one self-contained HTML page."""
    info = summary(result)
    page = Page("scanqa board calibration report")
    err = info["errors_px"]
    corners = f"corners {result.corner_method}; " if result.corner_method else ""
    page.paragraph(f"{corners}lens model {result.model}; reprojection RMS camera "
                   f"{err['cam_error']:.3f} px, projector {err['proj_error']:.3f} px, "
                   f"stereo {err['stereo_error']:.3f} px over {len(result.poses)} poses.")
    if info["flagged_poses"]:
        page.paragraph(f"Flagged ({info['flag_rule']}): {', '.join(info['flagged_poses'])}"
                       ": check the pose's images, or calibrate without it.", note=True)
    page.heading("Reprojection RMS per pose", "poses")
    fig, ax = new_figure()
    names = [p["pose"] for p in info["poses"]]
    x = np.arange(len(names))
    ax[0][0].bar(x - 0.2, [p["camera_rms_px"] for p in info["poses"]], 0.4, label="camera")
    ax[0][0].bar(x + 0.2, [p["projector_rms_px"] for p in info["poses"]], 0.4,
                 label="projector")
    ax[0][0].set_xticks(x, names)
    ax[0][0].set(ylabel="RMS reprojection error [px]", title="per pose")
    ax[0][0].legend()
    page.figure(fig, "RMS distance between each pose's corners and the fitted model",
                "poses")
    page.table(info["poses"])
    if info["held_out"]:
        page.heading("Each pose left out in turn", "held-out")
        page.paragraph("Calibrated on the other poses; on the pose left out: its projector "
                       "corners predicted from its camera corners, and the RMS of its "
                       "triangulated points about their plane (reference: the same pose "
                       "with the reference calibration, which may have seen it).")
        page.table(info["held_out"])
    if info["comparison"]:
        page.heading("Against the reference calibration", "reference")
        comp = info["comparison"]
        page.paragraph(f"reference: {comp['reference']}")
        page.table([{"quantity": k, "value": v} for k, v in comp.items()
                    if not isinstance(v, (dict, str))]
                   + [{"quantity": f"{k} [px]: ours / reference",
                       "value": f"{v:.3f} / {comp['reference_errors_px'].get(k, float('nan')):.3f}"}
                      for k, v in comp["errors_px"].items()])
    if info["board_flatness"]:
        flat = result.flatness
        page.heading("Is the board flat?", "flatness")
        page.paragraph(
            f"With every corner's position on the board fitted as well, the camera's RMS "
            f"goes from {flat['camera_rms_px']:.3f} to {flat['camera_rms_released_px']:.3f} "
            f"px, the board departing from its flat grid by {flat['out_of_plane_mm']:.3f} mm "
            f"out of plane and {flat['in_plane_mm']:.3f} mm in plane (RMS). Given that "
            f"board, the projector's RMS goes from {flat['projector_rms_px']:.3f} to "
            f"{flat['projector_rms_camera_board_px']:.3f} px (nan: OpenCV would not refit "
            "it): when it drops too, the residuals come from the board (a bent panel, the "
            "print), not from a lens model or the corner detector, and a flatter board is "
            "what lowers them.")
    if info["parameter_std"]:
        page.heading("Parameter standard deviations", "std")
        noise = info["joint_fit"]["noise_px"]
        page.paragraph("joint fit: from the Jacobian of the joint fit of camera, projector, "
                       "board poses and the board's bow, each device's residuals scaled by "
                       f"its corner noise (camera {noise.get('camera', float('nan')):.3f} px, "
                       f"projector {noise.get('projector', float('nan')):.3f} px), with the "
                       "lens terms the model leaves out as stated terms (what enters the "
                       "calibration sigma); jackknife: from the calibrations that left one "
                       "pose out (a check); OpenCV: from the Jacobian of its camera-only or "
                       "projector-only fit (lens parameters only).")
        fit, jack = info["parameter_std_fit"], info["parameter_std_jackknife"] or {}
        page.table([{"parameter": k, "joint fit": v, "jackknife": jack.get(k, ""),
                     "OpenCV": fit.get(k, "")}
                    for k, v in info["parameter_std"].items()])
        page.table([{"term": k, **{n: x for n, x in v.items()}}
                    for k, v in info["joint_fit"]["model_terms"].items()])
    return page.render()
