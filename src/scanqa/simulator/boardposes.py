"""Simulated board poses with a known camera-projector pair, for calibration studies.

Each seed draws a scanner (camera and projector lenses with radial k1 and k2, the
camera's principal point off the image centre by a few pixels, the projector beside the
camera), a chessboard bowed by a quadric sag, and board poses tilted about both axes. The
corners are projected (:func:`scanqa.calibration.pinhole.project_points`, OpenCV's
model) through the true lenses - the
camera's image corners and the projector's (what a perfect decode with local
homographies gives) - with Gaussian corner noise added. The study then calibrates from
these corners and compares the calibration's 3-D points with the truth
(:func:`volume_points`, :func:`point_errors`). Everything here is "simulated".
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanqa.calibration.board import Board, BoardPose
from scanqa.calibration.pinhole import (
    project_points,
    rotation_matrix,
    rotation_vector,
    undistort_points,
)
from scanqa.io.opencv import OpenCVCalibration
from scanqa.simulator import boardkernels

CAMERA = (1280, 1024)
PANEL = (912, 1140)
BOARD = Board(rows=8, columns=11, square_mm=10.0)


@dataclass(frozen=True)
class SimulatedBoardScanner:
    """One seed's truth and board poses.

    Attributes
    ----------
    truth : OpenCVCalibration
        The true camera, projector and their pose [px, -, mm].
    bow : (3,) float
        The board's quadric sag coefficients (x'^2, y'^2, x' y', x' y' in half sizes) [mm].
    noise_px : (float, float)
        Corner noise of camera and projector [px].
    poses : list of BoardPose
        The noisy corners of each pose.
    depth_mm : (float, float)
        Depth range of the poses' board centres [mm].
    """

    truth: OpenCVCalibration
    bow: np.ndarray
    noise_px: tuple
    poses: list
    depth_mm: tuple


def sag_mm(board: Board, bow: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The board's quadric sag at board coordinates ``xy`` (n, 2) [mm]: x', y' are in
    units of half the corner grid's size about its centre."""
    pts = board.object_points.astype(float)
    centre = (pts.max(axis=0) + pts.min(axis=0)) / 2
    half = np.maximum((pts.max(axis=0) - pts.min(axis=0)) / 2, 1e-9)
    x, y = (xy[:, 0] - centre[0]) / half[0], (xy[:, 1] - centre[1]) / half[1]
    return bow[0] * x**2 + bow[1] * y**2 + bow[2] * x * y


def gaussian_blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """``cv2.GaussianBlur(image, (0, 0), sigma_px)`` of a float image: OpenCV's kernel
    (radius round(4 sigma) for a float image, sampled and normalised) and its default
    border (reflect-101), as scipy's ``gaussian_filter(mode="mirror")`` computes it
    (:func:`scanqa.simulator.boardkernels.blur`) [DN]."""
    return boardkernels.blur(np.ascontiguousarray(image, dtype=float),
                             boardkernels.gaussian_weights(sigma_px))


def bowed_points(board: Board, bow: np.ndarray) -> np.ndarray:
    """(n, 3) board corners with the quadric sag as Z [mm]."""
    pts = board.object_points.astype(float)
    pts[:, 2] = sag_mm(board, bow, pts)
    return pts


@dataclass(frozen=True)
class ScannerClass:
    """The ranges one seed's scanner and board poses are drawn from (all uniform but
    the normal ``*_std`` terms).

    Attributes
    ----------
    camera, panel : (int, int)
        Camera image and projector panel (width, height) [px].
    focal_camera, focal_projector : (float, float)
        Focal length ranges [px].
    k1_camera, k1_projector : (float, float)
        Radial k1 ranges [-]; k2 is normal with std ``k2_std`` (camera, projector) [-].
    centre_std : float
        Std of the camera's principal point about the image centre [px].
    projector_cy : float
        The projector's principal point row as a share of the panel's height [-].
    tilt_y : (float, float)
        The projector's rotation about the camera's y axis [rad].
    projector_x : (float, float)
        The projector centre's x in the camera frame [mm] (its y and z: normal about
        ``projector_yz`` with std 5 mm).
    projector_yz : (float, float)
        [mm].
    depth : (float, float)
        The board centre's depth range [mm].
    lit_margin : float
        A pose is kept only if the board, out to this many squares beyond its corner
        grid, lies within the camera's image and the projector's panel (0: only the
        corners are checked) [-]. A real capture whose board margin lies outside the
        projector's light is taken again: the corner search needs the margin.
    """

    camera: tuple = CAMERA
    panel: tuple = PANEL
    focal_camera: tuple = (1700.0, 1900.0)
    focal_projector: tuple = (1250.0, 1400.0)
    k1_camera: tuple = (-0.12, -0.02)
    k1_projector: tuple = (-0.06, 0.0)
    k2_std: tuple = (0.05, 0.03)
    centre_std: float = 4.0
    projector_cy: float = 0.85
    tilt_y: tuple = (0.2, 0.3)
    projector_x: tuple = (100.0, 140.0)
    projector_yz: tuple = (10.0, -10.0)
    depth: tuple = (360.0, 440.0)
    lit_margin: float = 0.0


#: The scanner class the study was built on.
SCANNER = ScannerClass()
#: Another scanner class, for held-out checks: a 1024 x 768 camera with pincushion k1
#: and the projector on its left, a 1024 x 768 projector (Gray codes of 10 bits in both
#: directions), a farther and wider volume; with :data:`OTHER_BOARD`.
OTHER_SCANNER = ScannerClass(
    camera=(1024, 768), panel=(1024, 768), focal_camera=(1350.0, 1500.0),
    focal_projector=(1500.0, 1650.0), k1_camera=(0.02, 0.10), k1_projector=(-0.10, -0.03),
    k2_std=(0.08, 0.05), centre_std=6.0, projector_cy=0.78, tilt_y=(-0.26, -0.18),
    projector_x=(-150.0, -110.0), projector_yz=(-15.0, 5.0), depth=(470.0, 560.0),
    lit_margin=1.0)
#: The other scanner's board: 7 x 10 inner corners of 12 mm.
OTHER_BOARD = Board(rows=7, columns=10, square_mm=12.0)


def _truth(rng: np.random.Generator, scanner: ScannerClass = SCANNER) -> OpenCVCalibration:
    camera, panel = scanner.camera, scanner.panel
    f_c, f_p = rng.uniform(*scanner.focal_camera), rng.uniform(*scanner.focal_projector)
    kc = np.array([rng.uniform(*scanner.k1_camera), rng.normal(0, scanner.k2_std[0]), 0, 0,
                   0])
    kp = np.array([rng.uniform(*scanner.k1_projector), rng.normal(0, scanner.k2_std[1]), 0,
                   0, 0])
    cc = np.array([(camera[0] - 1) / 2, (camera[1] - 1) / 2]) + rng.normal(
        0, scanner.centre_std, 2)
    rot = rotation_matrix(np.array([rng.normal(0.03, 0.02), rng.uniform(*scanner.tilt_y),
                                 rng.normal(0, 0.02)]))
    centre = np.array([rng.uniform(*scanner.projector_x),
                       rng.normal(scanner.projector_yz[0], 5),
                       rng.normal(scanner.projector_yz[1], 5)])
    return OpenCVCalibration(
        Kc=np.array([[f_c, 0, cc[0]], [0, f_c, cc[1]], [0, 0, 1.0]]), kc=kc,
        Kp=np.array([[f_p, 0, panel[0] / 2 + rng.normal(0, 10)],
                     [0, f_p, scanner.projector_cy * panel[1] + rng.normal(0, 10)],
                     [0, 0, 1.0]]), kp=kp,
        Rp=rot, Tp=-rot @ centre,
        sizes={"frameWidth": camera[0], "frameHeight": camera[1], "screenResX": panel[0],
               "screenResY": panel[1]})


def simulate(seed: int, n_poses: int = 6, board: Board = BOARD, bow_mm: float = 0.15,
             noise_px: tuple | None = None, scanner: ScannerClass = SCANNER
             ) -> SimulatedBoardScanner:
    """One seed's scanner and board poses (module notes).

    Parameters
    ----------
    seed : int
        The random stream.
    n_poses : int
        Board poses [-].
    board : Board
        The chessboard (its grid and square size).
    bow_mm : float
        Std of each quadric sag coefficient [mm].
    noise_px : (float, float), optional
        Corner noise of camera and projector [px] (default drawn: 0.05-0.2 and
        0.03-0.12).
    scanner : ScannerClass
        The ranges the scanner and its poses are drawn from.

    Returns
    -------
    SimulatedBoardScanner
    """
    rng = np.random.default_rng(seed)
    truth = _truth(rng, scanner)
    bow = rng.normal(0, bow_mm, 3)
    noise = noise_px or (rng.uniform(0.05, 0.2), rng.uniform(0.03, 0.12))
    obj = bowed_points(board, bow)
    centre = (obj.max(axis=0) + obj.min(axis=0)) / 2
    poses, depths = [], []
    while len(poses) < n_poses:
        rvec = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4),
                         rng.uniform(-0.2, 0.2)])
        depth = rng.uniform(*scanner.depth)
        rmat = rotation_matrix(rvec)
        tvec = np.array([rng.normal(10, 15), rng.normal(0, 15), depth]) - rmat @ centre
        cam = project_points(obj, rvec, tvec, truth.Kc, truth.kc)
        rp = rotation_vector(truth.Rp @ rmat)
        proj = project_points(obj, rp, truth.Rp @ tvec + truth.Tp, truth.Kp, truth.kp)
        if not (within_margin(cam, scanner.camera, 20) and within_margin(proj, scanner.panel, 5)):
            continue
        if scanner.lit_margin and not _outline_inside(board, bow, scanner, truth, rvec,
                                                      tvec):
            continue
        cam = cam + noise[0] * rng.standard_normal(cam.shape)
        proj = proj + noise[1] * rng.standard_normal(proj.shape)
        empty = np.full((1, 1), np.nan)
        poses.append(BoardPose(f"sim{seed}_{len(poses)}", cam, proj, (0, 0, 1, 1), empty,
                               empty, scanner.camera, board))
        depths.append(depth)
    return SimulatedBoardScanner(truth, bow, tuple(noise), poses,
                                 (float(min(depths)), float(max(depths))))


def _outline_inside(board: Board, bow: np.ndarray, scanner: ScannerClass,
                    truth: OpenCVCalibration, rvec: np.ndarray, tvec: np.ndarray) -> bool:
    """The board's outline ``scanner.lit_margin`` squares beyond its corner grid (its
    sides sampled every half square) within the camera's image and the panel."""
    pts = board.object_points.astype(float)
    grow = scanner.lit_margin * board.square_mm
    (x0, y0), (x1, y1) = pts[:, :2].min(axis=0) - grow, pts[:, :2].max(axis=0) + grow
    n = int(np.ceil(2 * max(x1 - x0, y1 - y0) / board.square_mm)) + 1
    t = np.linspace(0.0, 1.0, n)
    xy = np.concatenate([np.column_stack([x0 + (x1 - x0) * t, np.full(n, y)])
                         for y in (y0, y1)]
                        + [np.column_stack([np.full(n, x), y0 + (y1 - y0) * t])
                           for x in (x0, x1)])
    outline = np.column_stack([xy, sag_mm(board, bow, xy)])
    rmat = rotation_matrix(rvec)
    cam = project_points(outline, rvec, tvec, truth.Kc, truth.kc)
    proj = project_points(outline, rotation_vector(truth.Rp @ rmat), truth.Rp @ tvec
                          + truth.Tp, truth.Kp, truth.kp)
    return within_margin(cam, scanner.camera, 2) and within_margin(proj, scanner.panel, 2)


def within_margin(px: np.ndarray, size: tuple, margin: float) -> bool:
    """Whether every point ``px`` [px] lies ``margin`` [px] or more inside an image of
    ``size`` (width, height) [px]."""
    return bool(np.all(px >= margin) and np.all(px[:, 0] <= size[0] - margin)
                and np.all(px[:, 1] <= size[1] - margin))


def volume_points(truth: OpenCVCalibration, depth_mm: tuple, grid: int = 7,
                  depths: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points spread over the calibrated volume: a grid of camera pixels at several
    depths, kept where the projector sees them.

    Returns
    -------
    u, v : (n,) float
        Camera pixels [px].
    xp : (n,) float
        Their true projector column [projector px].
    xyz : (n, 3) float
        The true points in the camera frame [mm].
    """
    camera = (truth.sizes["frameWidth"], truth.sizes["frameHeight"])
    panel = (truth.sizes["screenResX"], truth.sizes["screenResY"])
    uu, vv = np.meshgrid(np.linspace(0.1, 0.9, grid) * camera[0],
                         np.linspace(0.1, 0.9, grid) * camera[1])
    pix = np.column_stack([uu.ravel(), vv.ravel()])
    norm = undistort_points(pix, truth.Kc, truth.kc)
    out = []
    for z in np.linspace(*depth_mm, depths):
        xyz = np.column_stack([norm * z, np.full(len(norm), z)])
        prj = project_points(xyz, rotation_vector(truth.Rp), truth.Tp, truth.Kp, truth.kp)
        ok = (prj[:, 0] > 0) & (prj[:, 0] < panel[0]) & (prj[:, 1] > 0) & (
            prj[:, 1] < panel[1])
        out.append((pix[ok, 0], pix[ok, 1], prj[ok, 0], xyz[ok]))
    return tuple(np.concatenate(parts) for parts in zip(*out, strict=True))


ALBEDO = {"black": 0.15, "white": 0.85, "beyond": 0.05}
"""Reflectance of the board's black squares, its white squares and margin, and what lies
beyond the board [-]."""


def board_view(truth: OpenCVCalibration, board: Board, rvec: np.ndarray, tvec: np.ndarray,
               bow: np.ndarray | None = None, squares: bool = True) -> dict:
    """What each camera pixel sees of a board pose: its reflectance and its light's
    projector coordinates.

    Each camera pixel's ray meets the board (its plane, then the bowed surface: the
    sag ``bow`` along the board's normal at the point, found by two fixed-point steps
    along the ray, enough for sags of a millimetre); that one point's board coordinates
    give the reflectance (:data:`ALBEDO`: black squares, white squares and a white
    margin of one square around the grid; averaged over 3 x 3 points of the pixel's
    area) and its projector pixel the light.

    Parameters
    ----------
    truth : OpenCVCalibration
        The camera and projector.
    board : Board
        The chessboard; its frame has the corners at :attr:`Board.object_points`.
    rvec, tvec : (3,) float
        The board's pose in the camera frame (Rodrigues vector [rad], translation [mm]).
    bow : (3,) float, optional
        The board's quadric sag (:func:`sag_mm`) [mm].
    squares : bool
        False for a plain white plate over the whole view (a part to scan).

    Returns
    -------
    dict
        ``albedo`` (H, W) [-]; ``xp``, ``yp`` (H, W) projector coordinates of the point
        at the pixel's centre [projector px]; ``lit`` (H, W) bool, where the projector's
        panel reaches that point.
    """
    width, height = int(truth.sizes["frameWidth"]), int(truth.sizes["frameHeight"])
    v, u = np.mgrid[0:height, 0:width].astype(float)
    u, v = u.ravel(), v.ravel()
    rot = rotation_matrix(np.asarray(rvec, float))
    normal, origin = rot[:, 2], np.asarray(tvec, float)
    obj = board.object_points.astype(float)
    centre = (obj.max(axis=0) + obj.min(axis=0)) / 2  # sag_mm's x', y'
    half = np.maximum((obj.max(axis=0) - obj.min(axis=0)) / 2, 1e-9)
    sag = (np.zeros(3), 0) if bow is None else (np.asarray(bow, float), 2)

    def surface(du: float, dv: float, where: np.ndarray | slice = slice(None)
                ) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points and board coordinates seen at pixel offset (du, dv), at
        the pixels ``where`` (flat indices): the plane, then two fixed-point steps along
        the ray onto the bowed board (:func:`~scanqa.simulator.boardkernels.board_points`)."""
        norm = undistort_points(np.column_stack([u[where] + du, v[where] + dv]),
                                truth.Kc, truth.kc)
        return boardkernels.board_points(
            np.ascontiguousarray(norm[:, 0]), np.ascontiguousarray(norm[:, 1]), normal,
            origin, rot, float(normal @ origin), sag[0], centre[:2], half[:2], sag[1])

    def reflectance(local: np.ndarray) -> np.ndarray:
        return boardkernels.board_reflectance(local, float(board.square_mm), board.columns,
                                              board.rows, ALBEDO["white"], ALBEDO["black"],
                                              ALBEDO["beyond"])

    pts, local = surface(0.0, 0.0)
    if squares:
        # the pixel's area: reflectance averaged over a 3 x 3 grid of points within it;
        # the centre's points (offset 0, 0) are the ones lit and projected. Where the
        # centre lies more than a square beyond the board's margin, all nine points see
        # the background (a third of a pixel moves them by far less than a square), so
        # the other eight are only traced near the board: the same values, ~5 x less work.
        centre_shade = reflectance(local)
        s = board.square_mm
        near = np.flatnonzero((local[:, 0] > -3 * s) & (local[:, 0] < (board.columns + 2) * s)
                              & (local[:, 1] > -3 * s) & (local[:, 1] < (board.rows + 2) * s))
        total = None  # the nine in order, summed one after another, as np.mean's sum
        for du in (-1 / 3, 0, 1 / 3):
            for dv in (-1 / 3, 0, 1 / 3):
                if du == dv == 0:
                    shade = centre_shade
                else:
                    shade = np.full(len(centre_shade), ALBEDO["beyond"])
                    shade[near] = reflectance(surface(du, dv, near)[1])
                total = shade.copy() if total is None else total.__iadd__(shade)
        albedo = total / 9
    else:
        albedo = np.full(len(local), ALBEDO["white"])
    proj = project_points(pts, rotation_vector(truth.Rp), truth.Tp, truth.Kp, truth.kp)
    panel = (int(truth.sizes["screenResX"]), int(truth.sizes["screenResY"]))
    lit = ((proj[:, 0] > -0.5) & (proj[:, 0] < panel[0] - 0.5) & (proj[:, 1] > -0.5)
           & (proj[:, 1] < panel[1] - 0.5))
    shape = (height, width)
    return {"albedo": albedo.reshape(shape), "xp": proj[:, 0].reshape(shape),
            "yp": proj[:, 1].reshape(shape), "lit": lit.reshape(shape)}


def gray_frames(truth: OpenCVCalibration, board: Board, rvec: np.ndarray, tvec: np.ndarray,
                bits: tuple[int, int], rng: np.random.Generator, noise_dn: float = 2.0,
                blur_px: float = 0.7, bow: np.ndarray | None = None) -> dict:
    """8-bit frames of one board pose under Gray codes, as public projector-camera
    calibration tools capture them: for columns and for rows, every bit (most
    significant first, one projector pixel per code) followed by its inverse, then a
    white and a black frame.

    What each pixel sees is :func:`board_view`'s (the ray meets the bowed board; the
    reflectance averaged over the pixel's area; the light at its centre's projector
    pixel); then a Gaussian blur of ``blur_px`` and Gaussian noise of ``noise_dn``.

    Returns
    -------
    dict
        ``columns`` and ``rows``: (2 bits, H, W) uint8 frames; ``white``, ``black``:
        (H, W) uint8 [DN].
    """
    view = board_view(truth, board, rvec, tvec, bow)
    height, width = view["albedo"].shape
    gain, lit = 230.0 * view["albedo"], view["lit"]
    proj = np.column_stack([view["xp"].ravel(), view["yp"].ravel()])
    panel = (int(truth.sizes["screenResX"]), int(truth.sizes["screenResY"]))
    weights = boardkernels.gaussian_weights(blur_px)
    noise = np.empty((height, width))

    def shoot(light: np.ndarray) -> np.ndarray:
        # (8 + 230 albedo light where lit) blurred, plus the noise, rounded to 8 bits
        rng.standard_normal(noise.shape, out=noise)
        return boardkernels.fringe_shot(8.0, gain, np.where(lit, light.reshape(height, width),
                                                            0.0),
                                        weights, noise, noise_dn * noise_dn, 0.0)

    out = {}
    for key, axis, n in (("columns", 0, bits[0]), ("rows", 1, bits[1])):
        code = np.floor(np.clip(proj[:, axis], 0, panel[axis] - 1) + 0.5).astype(np.int64)
        code = code ^ (code >> 1)
        frames = []
        for b in range(n):
            bit = ((code >> (n - 1 - b)) & 1).astype(float)
            frames += [shoot(bit), shoot(1.0 - bit)]
        out[key] = np.array(frames)
    out["white"], out["black"] = shoot(np.ones(len(proj))), shoot(np.zeros(len(proj)))
    return out


def gray_descriptions(bits: tuple[int, int], panel: tuple[int, int]) -> tuple:
    """The column and row pattern descriptions of the folders :func:`write_gray_poses`
    writes: each bit with its inverse (interleaved, ``columns_00.png`` ...), then
    ``white.png`` and ``black.png``; ``bits`` and ``panel`` [px] as :func:`gray_frames`.
    """
    from scanqa.decoding.coding import GrayCodeSet, PatternDescription, ReferenceSet

    out = []
    for key, orientation, n, width in (("columns", "vertical", bits[0], panel[0]),
                                       ("rows", "horizontal", bits[1], panel[1])):
        names = tuple(f"{key}_{i:02d}.png" for i in range(2 * n))
        out.append(PatternDescription(width, (
            GrayCodeSet("gray", n, cell_px=1.0, inverse="interleaved",
                        threshold="inverse", orientation=orientation, files=names),
            ReferenceSet("wb", ("white", "black"), files=("white.png", "black.png")))))
    return out[0], out[1]


def write_gray_poses(sim: SimulatedBoardScanner, board: Board, bits: tuple[int, int],
                     seed: int, root, name: str = "pose{k}") -> list:
    """Each pose of ``sim`` rendered under Gray codes (:func:`gray_frames`, one random
    stream seeded by ``seed``) and written as 8-bit PNG files into ``root / name``
    (``{k}`` the pose's index), as :func:`gray_descriptions` names them; returns the
    folders. Needs OpenCV (the pose from the corners: ``solvePnP``)."""
    import cv2

    from scanqa.io.images import write_image

    rng = np.random.default_rng(seed)
    folders = []
    for k, pose in enumerate(sim.poses):
        _, rvec, tvec = cv2.solvePnP(board.object_points.astype(float), pose.camera_px,
                                     sim.truth.Kc, sim.truth.kc)
        frames = gray_frames(sim.truth, board, rvec.ravel(), tvec.ravel(), bits, rng,
                             bow=sim.bow)
        folder = Path(root) / name.format(k=k)
        folder.mkdir(parents=True, exist_ok=True)
        for key in ("columns", "rows"):
            for i, frame in enumerate(frames[key]):
                write_image(folder / f"{key}_{i:02d}.png", frame)
        write_image(folder / "white.png", frames["white"])
        write_image(folder / "black.png", frames["black"])
        folders.append(folder)
    return folders
