"""An independent scalar version of the defocus model (Eqs. 1-19 of Drouin et al. 2017).

:func:`reference_point` re-derives every quantity of :func:`scanqa.model.optics.predict` for one
point with the `math` module only: J1 from its power series (Abramowitz & Stegun 9.1.10)
instead of scipy, the projector axis and principal distance by hand from the pose and
Eq. 3 instead of the config's properties, and the triangulation scale from the angle of
the point seen from the projector (x_p = f_p' tan(phi - phi_axis)) differentiated
analytically along the camera ray, instead of the vector form in the code. It assumes a
projector that looks at a point of the scanner's XZ plane from that plane (as every
config in calib/ does).

The two-source model (docs/noise_model.rst) is written from its variances:
sigma_x^2 = (sigma_p^2 / F^2 + sigma_s^2) / (A_c A_p), with the "sum" filter factor
F^2 = (1 + b_disc + b_d) / gamma^2 built from the kernels' noise-equivalent areas
(pixel 1, defocus disc pi c_c^2 / 4 without Eq. 13's floor, Airy disc b_d; px^2), and
s_O = sigma_x / sigma_p.
"""

from __future__ import annotations

import math

READINGS = ("power", "amplitude", "mixed")
FLOORS = ("none", "one")
FORMS = ("product", "sum")


def bessel_j1(x: float) -> float:
    """J1 by its power series sum (-1)^k (x/2)^(2k+1) / (k! (k+1)!) (A&S 9.1.10)."""
    term = x / 2.0
    total = term
    for k in range(1, 60):
        term *= -(x / 2.0) ** 2 / (k * (k + 1))
        total += term
        if abs(term) < 1e-18 * max(abs(total), 1e-300):
            break
    return total


def attenuation(r: float) -> float:
    """Eq. 12: (2 J1(pi r) / (pi r))^2, 1 at r = 0."""
    x = math.pi * abs(r)
    return 1.0 if x == 0.0 else (2.0 * bessel_j1(x) / x) ** 2


def magnification(z_p: float, focus: float, focal: float) -> float:
    """Eq. 3 as printed."""
    return 2.0 * focal / (focus - 2.0 * focal + math.sqrt(z_p * (z_p - 4.0 * focal)))


def reference_point(q, cfg, reading: str, floor: str, period: float | None = None,
                    form: str = "product", sigma_s: float | None = None) -> dict:
    """Every quantity of the model for one point ``q`` (scanner frame) [mm]; ``sigma_s``
    the sensor's phase noise at focus [px] (default the config's; "two_source" only)."""
    cam, proj, model = cfg.camera, cfg.projector, cfg.model
    period = min(cfg.fringes.periods_px) if period is None else period
    x, y, z = (float(c) for c in q)
    px, _, pz = proj.position_mm
    ax, _, az = (proj.look_at_mm[0] - px, 0.0, proj.look_at_mm[2] - pz)  # axis in XZ
    norm = math.hypot(ax, az)
    z_c = z                                                     # camera axis = +Z
    z_p = ((x - px) * ax + (z - pz) * az) / norm                # along the projector axis
    pitch = proj.pitch_um * 1e-3
    omega_o = period * pitch / magnification(z_p, proj.focus_mm, proj.focal_mm)  # Eq. 4
    phi_c = cam.focal_mm / cam.f_number                         # Eq. 2: Phi = f / N
    coc_c = phi_c * abs(z_c - cam.focus_mm) / cam.focus_mm      # Eq. 1/2
    coc_p = proj.aperture_mm * abs(z_p - proj.focus_mm) / proj.focus_mm
    r_c, r_p = coc_c / omega_o, coc_p / omega_o
    a_c, a_p = attenuation(r_c), attenuation(r_p)
    s_c = cam.pixel_um * 1e-3
    c_image = cam.focal_mm / (z_c - cam.focal_mm) * coc_c       # Eq. 14
    b_c = max(math.pi * (c_image / (2 * s_c)) ** 2, 1.0)        # Eq. 13
    airy = 2 * 1.22 * model.wavelength_nm * 1e-6 * cam.f_number  # Eq. 15
    b_d = math.pi * (airy / (2 * s_c)) ** 2                     # Eq. 16
    if form == "product":
        f_1 = math.sqrt(b_c * b_d)                              # Eq. 17, gamma = 1
    else:  # noise-equivalent areas [px^2] of the pixel, the defocus disc, the Airy disc
        f_1 = math.sqrt(1.0 + math.pi * c_image**2 / (4 * s_c**2) + b_d)
    f = f_1 / model.gamma
    if floor == "one":
        f = max(f, 1.0)
    beyond = max(r_c, r_p) >= 1.2196698912665045                # first zero of J1(pi r)
    sigma_p = model.sigma_p_px
    if reading == "two_source":
        sig_s = model.sensor_sigma_p_px if sigma_s is None else sigma_s
        var_scene = sigma_p**2 / f**2 / (a_c * a_p) if a_c * a_p > 0 else math.inf
        var_sensor = sig_s**2 / (a_c * a_p) if a_c * a_p > 0 else math.inf
        if sig_s == 0.0:
            var_sensor = 0.0
        s_o = math.sqrt(var_scene + var_sensor) / sigma_p
        scene, sensor = math.sqrt(var_scene) / sigma_p, math.sqrt(var_sensor) / sigma_p
    else:
        a = {"power": a_p * a_c, "amplitude": math.sqrt(a_p * a_c),
             "mixed": math.sqrt(a_p) * a_c}[reading]
        s_o = scene = 1.0 / (f * a) if a > 0 else math.inf      # Eq. 19
        sensor = 0.0
    if beyond:
        s_o = scene = sensor = math.nan
    # s_T: the projector sees the point at angle phi from +Z (towards +X) in the XZ plane
    # (its y axis is the scanner's Y: it looks at a point with Y = 0 from Y = 0); its
    # column is x_p = f_p' tan(phi - phi_axis) with f_p' the pinhole distance that gives
    # Eq. 3's magnification at focus. Along the camera ray Q = t d, t = |Q|:
    # d(phi)/dt = (d_x (Z - pz) - (X - px) d_z) / rho^2, rho^2 = (X - px)^2 + (Z - pz)^2.
    f_p = magnification(proj.focus_mm, proj.focus_mm, proj.focal_mm) * proj.focus_mm / pitch
    t = math.sqrt(x * x + y * y + z * z)
    d_x, d_z = x / t, z / t
    rho2 = (x - px) ** 2 + (z - pz) ** 2
    dphi_dt = (d_x * (z - pz) - (x - px) * d_z) / rho2
    angle = math.atan2(x - px, z - pz) - math.atan2(ax, az)
    s_t = 1.0 / abs(f_p * dphi_dt / math.cos(angle) ** 2)
    sigma = s_t * s_o * sigma_p                                 # Eq. 18
    valid = r_c <= 0.5 and r_p <= 0.5 and math.isfinite(sigma)
    return {"z_c": z_c, "z_p": z_p, "omega_o": omega_o, "ratio_camera": r_c,
            "ratio_projector": r_p, "attenuation_camera": a_c, "attenuation_projector": a_p,
            "blur_area_camera": b_c, "filter_factor": f, "filter_base": f_1, "s_o": s_o,
            "s_o_scene": scene, "s_o_sensor": sensor, "s_t": s_t, "sigma": sigma,
            "sigma_scene": s_t * scene * sigma_p, "sigma_sensor": s_t * sensor * sigma_p,
            "valid": valid}
