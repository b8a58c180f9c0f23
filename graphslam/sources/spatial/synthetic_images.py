"""Synthetic image sequences for visual SLAM and loop closure (numpy + OpenCV).

The scene is a closed textured room (walls split into panels, a tiled floor
and ceiling) with textured boxes inside and around the route. Every surface is
a planar quad with its own texture, so each place looks different and has
plenty of corners for Harris/ORB.

Camera and frames: world ``z`` is up; the camera looks along its ``+z``, ``x``
right, ``y`` down; ``wTc`` (4, 4) maps camera points to world points. ``K`` uses
pixel centres at integer coordinates (OpenCV's convention), so projecting a 3-D
point with ``K`` and ``inv(wTc)`` lands where :func:`cv2.warpPerspective` drew it.

Trajectory: the camera drives counter-clockwise around a rounded rectangle
(``path_length_m`` x ``path_width_m``, corner radius ``corner_radius_m``,
centred in the room) for ``laps`` laps (default 1.5: one full lap then half a
lap again, so places are revisited), heading along the path, at height
``camera_height_m``. Small deterministic wobbles (lateral offset, height,
pitch) with periods that are not a multiple of the lap make revisits similar
but not pixel-identical.

Rendering (:meth:`SyntheticImageSequence.load`): per surface, the quad is
transformed into the camera frame, back-facing quads are culled, the polygon is
clipped in 3-D against the near plane ``z >= near_m`` (so quads crossing the
camera plane are handled exactly), projected, and its bounding box warped
from a mip level of the texture with the plane homography
``H = K [R a, R b, R o + t]``. A per-pixel inverse-depth z-buffer (inverse
depth is affine in pixel coordinates on a plane) composites the surfaces.

Odometry: ``odometry[k]`` (4, 4) is the noisy relative pose ``c_k T c_{k+1}``:
the true relative pose times ``E = [[exp(phi), rho], [0, 1]]`` with
``rho ~ N(0, sigma_t^2 I3)`` metres and ``phi ~ N(0, sigma_r^2 I3)`` radians
(rotation vector), drawn from ``default_rng(seed)``. The 6x6 covariance, in
order ``[rho, phi]``, is ``odometry_covariance``.

Revisit rule (:attr:`SyntheticImageSequence.revisit_pairs`): ``(i, j)`` with
``j - i >= revisit_min_gap_frames``, camera centres within
``revisit_distance_m`` and headings (yaw) within ``revisit_heading_deg``.
These are the revisits a detector must find (recall). A closure outside them
is still not false when its two frames see the same place
(:meth:`SyntheticImageSequence.same_place`: more than half of the scene points
one of them sees, occlusion included, are seen by the other): the closures
the loop benchmarks accept outside the rule, 0.4-1.4 m and 10-42 degrees from
their match, share 54-92 % of one view. This is the
"hard" and "soft" ground truth of place-recognition evaluation (Schubert et
al., "Visual Place Recognition: A Tutorial", IEEE RAM 2023): the hard pairs
must be found, the soft ones may be, and only a closure outside both is false.

Determinism: textures come from ``default_rng([seed, surface index])``; the same
config renders the same images to the bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import cv2
import numpy as np

from graphslam.sources.spatial.sequence import (
    FOCAL_MAX_PX,
    FOCAL_MIN_PX,
    PRINCIPAL_POINT_MAX_PX,
    ImageSequence,
)
from graphslam.sources.spatial.synthetic_render import (
    Surface,
    balbianello_photos,
    mip_levels,
    photo_texture,
    procedural_texture,
    render_surfaces,
)
from slamcore.config import Gate, Validated, bounded
from slamcore.errors import ConfigError, GraphSlamError
from slamcore.spatial.camera import intrinsics_matrix

__all__ = ["SyntheticImagesConfig", "SyntheticImageSequence", "make_synthetic_images"]

#: Largest image side, pixels: 8K video (7680 x 4320) is about the most a video
#: camera delivers. Each frame is rendered into an (H, W) uint8 image and a
#: float32 inverse-depth buffer (0.3 GB at 8192 x 8192), and the tracker builds
#: pyramids of it.
MAX_IMAGE_SIDE_PX = 8192
#: Most frames: revisit pairs are found by testing every frame against every
#: later one (n^2 / 2 pairs, 5e9 at 1e5 frames), and a run renders every frame;
#: 1e5 frames are already 2.8 hours of this sequence (10 frames per second).
MAX_FRAMES = 100_000
#: Largest room side, metres: the floor and ceiling are 2 m tiles and the walls
#: 4 m panels, each a textured surface that the renderer visits for every
#: frame, so their number grows with the area (5 000 at 100 m x 100 m).
MAX_ROOM_M = 100.0
#: Most texels of the room's level-0 textures together (1 GB of uint8, plus a
#: third for the mip levels), held in memory for the whole run: surface area x
#: texture_px_per_m^2; the default room at 100 px/m takes about 5e6.
MAX_TEXELS = 1_000_000_000


@dataclass(frozen=True)
class SyntheticImagesConfig(Validated):
    """Parameters of the synthetic image sequence (section ``[synthetic_images]``).

    Units: metres, radians for noise sigmas, degrees where the name says so,
    pixels for the camera.

    Attributes:
        seed: seeds the odometry noise (``default_rng(seed)``), each surface's
            texture (``default_rng([seed, surface index])``) and the pixel noise
            of frame i (``default_rng([seed, 1, i])``); part of each frame's
            pseudo-name. ``--seed`` overrides it.
        width, height: image size, pixels.
        fx, fy: focal lengths of the pinhole ``K``, pixels.
        cx, cy: principal point of ``K``, pixels, with pixel centres at integer
            coordinates; the defaults are the centre of the default 640 x 480
            image and do not follow ``width`` and ``height``.
        n_frames: number of frames, spread evenly in arc length over
            ``laps`` x the path's length (time stamps 0.1 s apart).
        laps: how many times the path is driven, may be fractional (default 1.5:
            one lap and then half of it again, so places are revisited).
        room_length_m: inside length of the room along world x, m; the room is
            centred on the origin. Walls are cut into panels of about 4 m.
        room_width_m: inside width of the room along world y, m.
        room_height_m: floor (z = 0) to ceiling height, m; also the height of
            the central box, which reaches the ceiling.
        path_length_m: extent of the rounded-rectangle path along x, m, centred
            in the room; it must leave 0.5 m + ``wobble_lateral_m`` to each wall.
            It also places the boxes.
        path_width_m: extent of the path along y, m; same rule.
        corner_radius_m: radius of the path's corners, m; at most half of
            ``path_length_m`` and ``path_width_m``.
        camera_height_m: height of the camera centre above the floor, m, before
            the height wobble; must be below ``room_height_m``.
        wobble_lateral_m: amplitude of a sideways offset from the path, m: a sine
            of arc length with a period of 0.77 path lengths.
        wobble_height_m: amplitude of the camera height's sine wobble, m, period
            23 frames.
        wobble_pitch_deg: amplitude of the camera pitch's sine wobble, degrees,
            period 37 frames.
        odometry_sigma_t_m: standard deviation of the translation noise of each
            odometry step, per axis, m; the noise ``E`` multiplies the true
            relative pose on the right. Runs report it as the stated odometry noise.
        odometry_sigma_r_rad: standard deviation of the rotation-vector noise of
            each odometry step, per axis, rad. The step covariance is
            ``diag([sigma_t^2] * 3 + [sigma_r^2] * 3)``.
        texture: "procedural" (seeded random blotches, rectangles, triangles,
            circles and lines) or "balbianello" (random crops of gtsam's
            Balbianello example photos; refused if gtsam does not ship them).
        texture_px_per_m: texels per metre of each surface's texture (at least
            16 a side); also sets how many corners ``points_w`` gets (up to one
            per 4000 texels). The room's textures may total at most 1e9 texels.
        pixel_noise_sigma: standard deviation of Gaussian noise added to every
            rendered pixel, in grey levels (0-255; the result is rounded and
            clipped); 0 renders noise-free images.
        near_m: near plane, m: surfaces are clipped to camera depth ``z >= near_m``
            and points at depth ``<= near_m`` count as not visible.
        revisit_distance_m: a revisit pair's camera centres are at most this far
            apart, m (3-D distance).
        revisit_heading_deg: a revisit pair's yaws (heading of the optical axis)
            differ by at most this, degrees.
        revisit_min_gap_frames: a revisit pair ``(i, j)`` has ``j - i`` at least
            this many frames.
    """

    SECTION: ClassVar[str] = "synthetic_images"
    #: the revisit rule scores loop detectors in the benchmarks; no command reads it
    #: (hostile pass 22: set in a run's config, it changed nothing, unsaid)
    REVISIT_KEYS: ClassVar[tuple[str, ...]] = (
        "revisit_distance_m",
        "revisit_heading_deg",
        "revisit_min_gap_frames",
    )
    #: the sequence's own odometry noise, unread where the run takes other odometry
    ODOMETRY_KEYS: ClassVar[tuple[str, ...]] = ("odometry_sigma_t_m", "odometry_sigma_r_rad")
    GATES: ClassVar[tuple[Gate, ...]] = (
        Gate(
            REVISIT_KEYS,
            "the benchmarks' scoring of loop detectors (bench_loop_pr.py, bench_loop_ate.py, "
            "bench_loop_revisit.py); no command reads them",
            lambda c: False,
        ),
    )

    seed: int = bounded(0, min=0)
    width: int = bounded(640, min=16, max=MAX_IMAGE_SIDE_PX)
    height: int = bounded(480, min=16, max=MAX_IMAGE_SIDE_PX)
    # the focal lengths an intrinsics file may give; fx = 1e-12 hung the renderer
    fx: float = bounded(500.0, min=FOCAL_MIN_PX, max=FOCAL_MAX_PX)
    fy: float = bounded(500.0, min=FOCAL_MIN_PX, max=FOCAL_MAX_PX)
    cx: float = bounded(319.5, min=-PRINCIPAL_POINT_MAX_PX, max=PRINCIPAL_POINT_MAX_PX)
    cy: float = bounded(239.5, min=-PRINCIPAL_POINT_MAX_PX, max=PRINCIPAL_POINT_MAX_PX)
    n_frames: int = bounded(300, min=2, max=MAX_FRAMES)
    laps: float = bounded(1.5, gt=0.0)
    room_length_m: float = bounded(16.0, gt=0.0, max=MAX_ROOM_M)
    room_width_m: float = bounded(11.0, gt=0.0, max=MAX_ROOM_M)
    room_height_m: float = bounded(3.0, gt=0.0, max=MAX_ROOM_M)
    path_length_m: float = bounded(10.0, gt=0.0)
    path_width_m: float = bounded(5.0, gt=0.0)
    corner_radius_m: float = bounded(1.5, gt=0.0)
    camera_height_m: float = bounded(1.4, gt=0.0)
    wobble_lateral_m: float = bounded(0.15, min=0.0)
    wobble_height_m: float = bounded(0.05, min=0.0)
    #: a pitch of 90 degrees or more looks at the floor or beyond: no walk through a room
    wobble_pitch_deg: float = bounded(2.0, min=0.0, lt=90.0)
    odometry_sigma_t_m: float = bounded(0.01, min=0.0)
    odometry_sigma_r_rad: float = bounded(0.002, min=0.0)
    texture: Literal["procedural", "balbianello"] = "procedural"
    texture_px_per_m: float = bounded(100.0, gt=0.0)
    pixel_noise_sigma: float = bounded(0.0, min=0.0)
    near_m: float = bounded(0.05, gt=0.0)
    revisit_distance_m: float = bounded(1.0, min=0.0)
    revisit_heading_deg: float = bounded(10.0, min=0.0)
    revisit_min_gap_frames: int = bounded(50, min=1)

    def __post_init__(self):
        super().__post_init__()
        s = f"{self.SECTION}."
        if self.corner_radius_m > min(self.path_length_m, self.path_width_m) / 2:
            raise ConfigError(
                f"{s}corner_radius_m must be <= half of path_length_m and "
                f"path_width_m, got {float(self.corner_radius_m)}"
            )
        margin = 0.5 + self.wobble_lateral_m
        if self.path_length_m / 2 + margin > self.room_length_m / 2:
            raise ConfigError(
                f"{s}path_length_m must fit in room_length_m with 0.5 m + "
                f"wobble_lateral_m to spare at each end, got {float(self.path_length_m)}"
            )
        if self.path_width_m / 2 + margin > self.room_width_m / 2:
            raise ConfigError(
                f"{s}path_width_m must fit in room_width_m with 0.5 m + "
                f"wobble_lateral_m to spare at each side, got {float(self.path_width_m)}"
            )
        if not self.camera_height_m < self.room_height_m:
            raise ConfigError(
                f"{s}camera_height_m must be < room_height_m "
                f"({float(self.room_height_m)}), got {float(self.camera_height_m)}"
            )
        if (
            not 0.0
            < self.camera_height_m - self.wobble_height_m
            <= (self.camera_height_m + self.wobble_height_m)
            < self.room_height_m
        ):
            raise ConfigError(
                f"{s}wobble_height_m ({float(self.wobble_height_m)}) would take the camera "
                f"through the floor or the ceiling (camera_height_m {float(self.camera_height_m)}, "
                f"room_height_m {float(self.room_height_m)})"
            )
        L, W, H = self.room_length_m, self.room_width_m, self.room_height_m
        # a product, not ** 2: a float power that overflows raises, a product is inf
        texels = (2 * L * W + 2 * (L + W) * H) * self.texture_px_per_m * self.texture_px_per_m
        if texels > MAX_TEXELS:
            raise ConfigError(
                f"{s}texture_px_per_m: the room's textures would take {texels:.3g} "
                f"texels; at most {MAX_TEXELS:.0e} (memory)"
            )


# ------------------------------------------------------------------------- scene


def _quads(cfg: SyntheticImagesConfig) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, corners (4, 3), normal) of every surface, room first then boxes."""
    Lx, Ly, Hz = cfg.room_length_m / 2, cfg.room_width_m / 2, cfg.room_height_m
    quads = []

    def quad(name, o, A, B, normal):
        o, A, B = (np.asarray(v, dtype=np.float64) for v in (o, A, B))
        quads.append((name, np.array([o, o + A, o + A + B, o + B]), np.asarray(normal, float)))

    # Walls, split into ~4 m panels; texture "up" (B) points down so rows go down.
    walls = [  # (start corner, direction along wall, length, inward normal)
        ((-Lx, -Ly), (1, 0), 2 * Lx, (0, 1, 0)),
        ((Lx, -Ly), (0, 1), 2 * Ly, (-1, 0, 0)),
        ((Lx, Ly), (-1, 0), 2 * Lx, (0, -1, 0)),
        ((-Lx, Ly), (0, -1), 2 * Ly, (1, 0, 0)),
    ]
    for wi, (start, d, length, n) in enumerate(walls):
        k = max(1, round(length / 4.0))
        seg = length / k
        for p in range(k):
            o = (start[0] + d[0] * seg * p, start[1] + d[1] * seg * p, Hz)
            # Seen from inside: along-wall direction d is to the viewer's left when
            # normal is n; use -d... choose A so that A x B points along n.
            A = np.array([d[0] * seg, d[1] * seg, 0.0])
            B = np.array([0.0, 0.0, -Hz])
            if np.dot(np.cross(A, B), n) < 0:
                o = (o[0] + A[0], o[1] + A[1], Hz)
                A = -A
            quad(f"wall{wi}.{p}", o, A, B, n)
    # Floor and ceiling tiles (2 m).
    nx, ny = max(1, round(2 * Lx / 2.0)), max(1, round(2 * Ly / 2.0))
    sx, sy = 2 * Lx / nx, 2 * Ly / ny
    for i in range(nx):
        for j in range(ny):
            x0, y0 = -Lx + i * sx, -Ly + j * sy
            quad(f"floor{i}.{j}", (x0, y0 + sy, 0), (sx, 0, 0), (0, -sy, 0), (0, 0, 1))
            quad(f"ceiling{i}.{j}", (x0, y0, Hz), (sx, 0, 0), (0, sy, 0), (0, 0, -1))
    # Boxes: centre (x, y), half sizes (hx, hy), height; inside and outside the loop.
    px, py = cfg.path_length_m / 2, cfg.path_width_m / 2
    gap_x = (Lx - px) / 2
    gap_y = (Ly - py) / 2
    boxes = [
        ((-px / 2, 0.0), (0.5, 0.5), 2.0),
        ((px / 2, 0.0), (0.4, 0.6), 1.2),
        ((0.0, 0.0), (0.3, 0.3), Hz),
        ((px + gap_x, py + gap_y), (0.5, 0.4), 1.0),
        ((-px - gap_x, -py - gap_y), (0.4, 0.5), 1.6),
        ((0.0, py + gap_y), (0.6, 0.3), 0.8),
        ((0.0, -py - gap_y), (0.3, 0.5), 2.2),
        ((-px - gap_x, py + gap_y * 0.5), (0.35, 0.35), 1.3),
    ]
    for bi, ((cx, cy), (hx, hy), hz) in enumerate(boxes):
        if min(gap_x, gap_y) < 0.9 and bi >= 3:
            continue  # no room between path and walls for outer boxes
        x0, x1, y0, y1 = cx - hx, cx + hx, cy - hy, cy + hy
        quad(f"box{bi}.-y", (x0, y0, hz), (2 * hx, 0, 0), (0, 0, -hz), (0, -1, 0))
        quad(f"box{bi}.+x", (x1, y0, hz), (0, 2 * hy, 0), (0, 0, -hz), (1, 0, 0))
        quad(f"box{bi}.+y", (x1, y1, hz), (-2 * hx, 0, 0), (0, 0, -hz), (0, 1, 0))
        quad(f"box{bi}.-x", (x0, y1, hz), (0, -2 * hy, 0), (0, 0, -hz), (-1, 0, 0))
        if hz < Hz - 1e-6:
            quad(f"box{bi}.top", (x0, y1, hz), (2 * hx, 0, 0), (0, -2 * hy, 0), (0, 0, 1))
    return quads


def _path(cfg: SyntheticImagesConfig, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rounded-rectangle path: arc length s (m) -> (x, y, heading), CCW from the bottom straight."""
    a, b, r = cfg.path_length_m / 2, cfg.path_width_m / 2, cfg.corner_radius_m
    lx, ly = 2 * (a - r), 2 * (b - r)
    arc = 0.5 * math.pi * r
    # (kind, start or centre, direction or start angle, length)
    segs: list[tuple[str, tuple[float, float], tuple[float, float] | float, float]] = [
        ("line", (-a + r, -b), (1, 0), lx),
        ("arc", (a - r, -b + r), -0.5 * math.pi, arc),
        ("line", (a, -b + r), (0, 1), ly),
        ("arc", (a - r, b - r), 0.0, arc),
        ("line", (a - r, b), (-1, 0), lx),
        ("arc", (-a + r, b - r), 0.5 * math.pi, arc),
        ("line", (-a, b - r), (0, -1), ly),
        ("arc", (-a + r, -b + r), math.pi, arc),
    ]
    total = sum(sg[3] for sg in segs)
    s = np.mod(s, total)
    x, y, h = np.zeros_like(s), np.zeros_like(s), np.zeros_like(s)
    start = 0.0
    for _, p, q, length in segs:
        m = (s >= start) & (s < start + length + 1e-12)
        d = s[m] - start
        if isinstance(q, tuple):  # a "line": q is its direction; an "arc": its start angle
            x[m], y[m] = p[0] + q[0] * d, p[1] + q[1] * d
            h[m] = math.atan2(q[1], q[0])
        else:
            ang = q + d / r
            x[m], y[m] = p[0] + r * np.cos(ang), p[1] + r * np.sin(ang)
            h[m] = ang + 0.5 * math.pi
        start += length
    return x, y, h


def _path_length(cfg: SyntheticImagesConfig) -> float:
    a, b, r = cfg.path_length_m / 2, cfg.path_width_m / 2, cfg.corner_radius_m
    return 4 * (a - r) + 4 * (b - r) + 2 * math.pi * r


def _trajectory(cfg: SyntheticImagesConfig) -> np.ndarray:
    """(N, 4, 4) wTc of the camera along the path, with the wobbles."""
    L = _path_length(cfg)
    n = cfg.n_frames
    s = np.linspace(0.0, cfg.laps * L, n, endpoint=False)
    x, y, yaw = _path(cfg, s)
    k = np.arange(n)
    lateral = cfg.wobble_lateral_m * np.sin(2 * np.pi * s / (0.77 * L))
    x = x - np.sin(yaw) * lateral
    y = y + np.cos(yaw) * lateral
    z = cfg.camera_height_m + cfg.wobble_height_m * np.sin(2 * np.pi * k / 23.0)
    pitch = np.deg2rad(cfg.wobble_pitch_deg) * np.sin(2 * np.pi * k / 37.0)
    wTc = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        fwd = np.array(
            [math.cos(yaw[i]) * math.cos(pitch[i]), math.sin(yaw[i]) * math.cos(pitch[i]), math.sin(pitch[i])]
        )
        right = np.array([math.sin(yaw[i]), -math.cos(yaw[i]), 0.0])
        down = np.cross(fwd, right)
        wTc[i, :3, :3] = np.column_stack([right, down, fwd])
        wTc[i, :3, 3] = [x[i], y[i], z[i]]
    return wTc


def _so3_exp(phi: np.ndarray) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.asarray(phi, dtype=np.float64).reshape(3, 1))
    return R


def _invert(T: np.ndarray) -> np.ndarray:
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def _yaw(wTc: np.ndarray) -> np.ndarray:
    fwd = wTc[..., :3, 2]
    return np.arctan2(fwd[..., 1], fwd[..., 0])


# ------------------------------------------------------------------------- sequence


@dataclass(frozen=True, eq=False, kw_only=True)
class SyntheticImageSequence(ImageSequence):
    """An :class:`ImageSequence` rendered on demand, with its ground truth.

    Extra attributes:
        config: the :class:`SyntheticImagesConfig` it was made from.
        odometry: (N-1, 4, 4) noisy relative poses ``c_k T c_{k+1}``.
        odometry_sigmas: ``(sigma_t_m, sigma_r_rad)`` per frame.
        odometry_covariance: (6, 6) ``diag([sigma_t^2]*3 + [sigma_r^2]*3)``, order ``[rho, phi]``.
        points_w: (M, 3) texture corners (goodFeaturesToTrack on each texture) in world.
        point_surface: (M,) index into ``surfaces`` of each point.
        surfaces: the textured quads.
        revisit_pairs: ``(i, j)`` frame pairs seeing the same place (rule in the module doc).

    ``image_paths`` holds pseudo-names (``synthetic:seed=S:frame=00042``); read
    images with :meth:`load`, never with ``cv2.imread``.
    """

    config: SyntheticImagesConfig
    odometry: np.ndarray
    odometry_sigmas: tuple[float, float]
    odometry_covariance: np.ndarray
    points_w: np.ndarray
    point_surface: np.ndarray
    surfaces: tuple[Surface, ...]
    revisit_pairs: list[tuple[int, int]] = field(default_factory=list)

    def load(self, i: int) -> np.ndarray:
        """Frame ``i`` as (H, W) uint8 greyscale (rendered, deterministic)."""
        return self.render(i)[0]

    load_raw = load  # rendered through the pinhole K: nothing to undistort

    def _true_wTc(self, i: int) -> np.ndarray:
        """Frame ``i``'s ground-truth pose (a synthetic sequence is made with them)."""
        if self.wTc_true is None:
            raise GraphSlamError("synthetic images: the sequence has lost its ground truth")
        return self.wTc_true[i]

    @property
    def nearest_depth_m(self) -> float | None:
        """1st percentile (a few corners grazing a box's edge are nearer than any trackable
        point) of the depths of the points in front and inside the image over every frame,
        occlusion ignored, metres: 3.0 for the default room (in view 1.7-12 m, median 6 m)."""
        (W, H), depths = self.image_size, [np.zeros(0)]
        for i in range(len(self)):
            uv, z = self.project(i)
            depths.append(
                z[
                    (z > self.config.near_m)
                    & (uv[:, 0] >= 0)
                    & (uv[:, 0] <= W - 1)
                    & (uv[:, 1] >= 0)
                    & (uv[:, 1] <= H - 1)
                ]
            )
        d = np.concatenate(depths)
        return float(np.percentile(d, 1.0)) if len(d) else None

    def render(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """``(image (H, W) uint8, depth (H, W) float32 metres, inf where empty)`` of frame ``i``."""
        n = len(self.image_paths)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range [0, {n})")
        i %= n
        img, invz = render_surfaces(
            self.surfaces, self.K, _invert(self._true_wTc(i)), self.image_size, self.config.near_m
        )
        if self.config.pixel_noise_sigma > 0:
            rng = np.random.default_rng([self.config.seed, 1, i])
            noisy = img.astype(np.float32) + rng.normal(0, self.config.pixel_noise_sigma, img.shape)
            img = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        with np.errstate(divide="ignore"):
            depth = np.where(invz > 0, 1.0 / invz, np.inf).astype(np.float32)
        return img, depth

    def project(self, i: int, points_w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(uv (M, 2) pixels, depth (M,) metres)`` of world points in frame ``i``."""
        P = self.points_w if points_w is None else np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
        cTw = _invert(self._true_wTc(i))
        pc = P @ cTw[:3, :3].T + cTw[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = pc @ self.K.T
            uv = uvw[:, :2] / uvw[:, 2:3]
        return uv, pc[:, 2]

    #: :meth:`same_place`: the share of one view's scene points the other must see.
    SAME_PLACE_SHARE: ClassVar[float] = 0.5

    def shared_view(self, i: int, j: int) -> float:
        """The larger of the shares of the scene points frame ``i`` sees that frame ``j``
        also sees, and the reverse (:meth:`visible_points`, occlusion included); 0 when
        either sees none."""
        a, b = set(self.visible_points(i).tolist()), set(self.visible_points(j).tolist())
        if not a or not b:
            return 0.0
        both = len(a & b)
        return max(both / len(a), both / len(b))

    def same_place(self, i: int, j: int) -> bool:
        """Frames ``i`` and ``j`` see the same place: more than :data:`SAME_PLACE_SHARE` of
        one view's scene points are seen by the other (the soft truth of the module doc)."""
        return self.shared_view(i, j) > self.SAME_PLACE_SHARE

    def later_visit(self, i: int, j: int) -> bool:
        """Frame ``i`` sees the place of the earlier frame ``j`` again: :meth:`same_place`,
        at least ``revisit_min_gap_frames`` later (a recent frame sees the same place
        because the camera has not left it: no loop)."""
        return i - j >= self.config.revisit_min_gap_frames and self.same_place(i, j)

    def visible_points(
        self, i: int, depth_map: np.ndarray | None = None, border_px: float = 0.0, depth_tol: float = 0.02
    ) -> np.ndarray:
        """Indices of ``points_w`` seen in frame ``i``: in front, inside the image
        (``border_px`` margin) and not occluded (depth within ``depth_tol`` relative)."""
        if depth_map is None:
            depth_map = self.render(i)[1]
        uv, z = self.project(i)
        W, H = self.image_size
        ok = (z > self.config.near_m) & np.all(np.isfinite(uv), axis=1)
        ok &= (uv[:, 0] >= border_px) & (uv[:, 0] <= W - 1 - border_px)
        ok &= (uv[:, 1] >= border_px) & (uv[:, 1] <= H - 1 - border_px)
        idx = np.flatnonzero(ok)
        px = np.rint(uv[idx]).astype(int)
        d = depth_map[px[:, 1], px[:, 0]]
        good = np.abs(d - z[idx]) <= depth_tol * z[idx]
        return idx[good]


def make_synthetic_images(config: SyntheticImagesConfig | None = None) -> SyntheticImageSequence:
    """Build the scene, trajectory, noisy odometry and revisit pairs of ``config``."""
    cfg = config or SyntheticImagesConfig()
    photos = balbianello_photos() if cfg.texture == "balbianello" else None
    surfaces, pts, owner = [], [], []
    for si, (name, corners, normal) in enumerate(_quads(cfg)):
        A = np.linalg.norm(corners[1] - corners[0])
        B = np.linalg.norm(corners[3] - corners[0])
        tw = max(16, int(round(A * cfg.texture_px_per_m)))
        th = max(16, int(round(B * cfg.texture_px_per_m)))
        rng = np.random.default_rng([cfg.seed, si])
        if photos is None:
            tex = procedural_texture(rng, tw, th)
        else:
            tex = photo_texture(rng, photos, tw, th)
        surf = Surface(name, corners, normal, mip_levels(tex))
        surfaces.append(surf)
        corners_uv = cv2.goodFeaturesToTrack(
            tex, maxCorners=max(4, int(tw * th / 4000)), qualityLevel=0.05, minDistance=10, blockSize=5
        )
        if corners_uv is not None:
            uv = corners_uv.reshape(-1, 2)
            inner = (uv[:, 0] >= 8) & (uv[:, 0] <= tw - 9) & (uv[:, 1] >= 8) & (uv[:, 1] <= th - 9)
            pts.append(surf.texel_to_world(uv[inner]))
            owner.append(np.full(int(inner.sum()), si))
    points_w = np.concatenate(pts) if pts else np.zeros((0, 3))
    point_surface = np.concatenate(owner) if owner else np.zeros(0, int)

    wTc = _trajectory(cfg)
    n = cfg.n_frames
    rng = np.random.default_rng(cfg.seed)
    odo = np.empty((n - 1, 4, 4))
    for k in range(n - 1):
        E = np.eye(4)
        E[:3, 3] = rng.normal(0.0, cfg.odometry_sigma_t_m, 3)
        E[:3, :3] = _so3_exp(rng.normal(0.0, cfg.odometry_sigma_r_rad, 3))
        odo[k] = _invert(wTc[k]) @ wTc[k + 1] @ E
    cov = np.diag([cfg.odometry_sigma_t_m**2] * 3 + [cfg.odometry_sigma_r_rad**2] * 3)

    pos = wTc[:, :3, 3]
    yaw = _yaw(wTc)
    pairs: list[tuple[int, int]] = []
    for i in range(n):
        j = np.arange(i + cfg.revisit_min_gap_frames, n)
        if j.size == 0:
            break
        close = np.linalg.norm(pos[j] - pos[i], axis=1) <= cfg.revisit_distance_m
        dyaw = np.abs((yaw[j] - yaw[i] + np.pi) % (2 * np.pi) - np.pi)
        close &= dyaw <= np.deg2rad(cfg.revisit_heading_deg)
        pairs.extend((i, int(jj)) for jj in j[close])

    K = intrinsics_matrix(cfg.fx, cfg.fy, cfg.cx, cfg.cy)
    paths = [f"synthetic:seed={cfg.seed}:frame={k:05d}" for k in range(n)]
    return SyntheticImageSequence(
        name="synthetic-images",
        image_paths=paths,
        stamps_s=np.arange(n, dtype=np.float64) * 0.1,
        K=K,
        distortion=None,
        wTc_true=wTc,
        image_size=(cfg.width, cfg.height),
        source_path=None,
        config=cfg,
        odometry=odo,
        odometry_sigmas=(cfg.odometry_sigma_t_m, cfg.odometry_sigma_r_rad),
        odometry_covariance=cov,
        points_w=points_w,
        point_surface=point_surface,
        surfaces=tuple(surfaces),
        revisit_pairs=pairs,
    )
