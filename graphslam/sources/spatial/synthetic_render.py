"""The synthetic room's surfaces: textured planar quads, their textures, and how a frame is drawn.

Split from :mod:`graphslam.sources.spatial.synthetic_images` (which builds the
room, the trajectory and the odometry, and documents the conventions): here
is what does not depend on the sequence's configuration. :class:`Surface`
holds a quad and its texture pyramid; :func:`render_surfaces` draws a set of
them through a pinhole camera with a per-pixel inverse-depth z-buffer
(OpenCV warps each quad's bounding box with its plane homography: no
rasteriser library does textured planar quads with exact near-plane
clipping and an inverse-depth buffer in numpy + OpenCV alone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from slamcore.errors import ConfigError

__all__ = [
    "Surface",
    "clip_polygon_near",
    "procedural_texture",
    "balbianello_photos",
    "photo_texture",
    "mip_levels",
    "render_surfaces",
]


@dataclass(frozen=True, eq=False)
class Surface:
    """A textured planar quad.

    ``corners_w`` (4, 3): ``o, o + A, o + A + B, o + B`` counter-clockwise seen
    from the visible side; texel ``(u, v)`` (column, row, centres at integers)
    of the level-0 texture (``th`` x ``tw``) is at ``o + (u+0.5)/tw A + (v+0.5)/th B``.
    ``normal_w`` points to the visible side. ``mips``: texture pyramid (uint8).
    """

    name: str
    corners_w: np.ndarray
    normal_w: np.ndarray
    mips: tuple[np.ndarray, ...]

    def texel_to_world(self, uv: np.ndarray) -> np.ndarray:
        """(M, 2) level-0 texel coordinates -> (M, 3) world points."""
        th, tw = self.mips[0].shape
        c = self.corners_w
        o, A, B = c[0], c[1] - c[0], c[3] - c[0]
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        return o + np.outer((uv[:, 0] + 0.5) / tw, A) + np.outer((uv[:, 1] + 0.5) / th, B)


def clip_polygon_near(poly_c: np.ndarray, near: float) -> np.ndarray:
    """Sutherland-Hodgman clip of a (M, 3) camera-frame polygon to ``z >= near``."""
    out = []
    n = len(poly_c)
    for k in range(n):
        p, q = poly_c[k], poly_c[(k + 1) % n]
        p_in, q_in = p[2] >= near, q[2] >= near
        if p_in:
            out.append(p)
        if p_in != q_in:
            s = (near - p[2]) / (q[2] - p[2])
            out.append(p + s * (q - p))
    return np.array(out).reshape(-1, 3)


def procedural_texture(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """Distinct, corner-rich greyscale texture: blotchy background + random shapes."""
    small = rng.uniform(60, 190, size=(max(2, h // 40), max(2, w // 40))).astype(np.float32)
    img = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    img = np.clip(img, 0, 255).astype(np.uint8)
    n_shapes = int(max(8, w * h / 900))
    for _ in range(n_shapes):
        kind = rng.integers(0, 4)
        g = int(rng.integers(0, 256))
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        s = int(rng.integers(6, 28))
        if kind == 0:
            cv2.rectangle(img, (x, y), (x + s, y + int(rng.integers(6, 28))), g, -1)
        elif kind == 1:
            pts = np.array(
                [[x, y], [x + s, y + int(rng.integers(-s, s))], [x + int(rng.integers(-s, s)), y + s]],
                np.int32,
            )
            cv2.fillConvexPoly(img, pts, g)
        elif kind == 2:
            cv2.circle(img, (x, y), s // 2, g, -1)
        else:
            end = (x + int(rng.integers(-3 * s, 3 * s)), y + int(rng.integers(-3 * s, 3 * s)))
            cv2.line(img, (x, y), end, g, int(rng.integers(1, 4)))
    return img


def balbianello_photos() -> list[np.ndarray]:
    import glob
    import os

    import gtsam  # only for the example-data path; see the module doc

    try:
        folder = gtsam.findExampleDataFile("Balbianello")
    except Exception:
        folder = None
    if not folder or not os.path.isdir(folder):
        raise ConfigError("texture 'balbianello': gtsam's Balbianello example folder was not found")
    read = [cv2.imread(p, cv2.IMREAD_GRAYSCALE) for p in sorted(glob.glob(os.path.join(folder, "*.jpg")))]
    photos = [p for p in read if p is not None]
    if not photos:
        raise ConfigError(f"texture 'balbianello': no readable .jpg in {folder}")
    return photos


def photo_texture(rng: np.random.Generator, photos: list[np.ndarray], w: int, h: int) -> np.ndarray:
    """A random crop of a random photo, resized to (h, w)."""
    ph = photos[int(rng.integers(len(photos)))]
    H, W = ph.shape
    scale = rng.uniform(0.3, 0.7)
    cw = int(W * scale)
    ch = int(min(H, cw * h / w))
    cw = int(ch * w / h)
    x0, y0 = int(rng.integers(0, W - cw + 1)), int(rng.integers(0, H - ch + 1))
    if rng.random() < 0.5:
        crop = ph[y0 : y0 + ch, x0 : x0 + cw][:, ::-1]
    else:
        crop = ph[y0 : y0 + ch, x0 : x0 + cw]
    return cv2.resize(np.ascontiguousarray(crop), (w, h), interpolation=cv2.INTER_AREA)


def mip_levels(tex: np.ndarray, levels: int = 5) -> tuple[np.ndarray, ...]:
    out = [tex]
    while len(out) < levels and min(out[-1].shape) >= 16:
        out.append(cv2.pyrDown(out[-1]))
    return tuple(out)


def render_surfaces(
    surfaces, K: np.ndarray, cTw: np.ndarray, size: tuple[int, int], near: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(image (H, W) uint8, inverse depth (H, W) float32, 0 where empty)`` of ``surfaces``
    seen from ``cTw`` through ``K`` (module docstring of :mod:`.synthetic_images`)."""
    W, H = size
    img = np.zeros((H, W), np.uint8)
    invz = np.zeros((H, W), np.float32)
    R, t = cTw[:3, :3], cTw[:3, 3]
    cam_w = -R.T @ t
    Kinv = np.linalg.inv(K)
    for surf in surfaces:
        c = surf.corners_w
        if np.dot(surf.normal_w, cam_w - c[0]) <= 1e-9:
            continue  # back-facing (or edge-on)
        pc = c @ R.T + t
        if np.all(pc[:, 2] < near):
            continue
        poly = clip_polygon_near(pc, near) if np.any(pc[:, 2] < near) else pc
        if len(poly) < 3:
            continue
        uvw = poly @ K.T
        uv = uvw[:, :2] / uvw[:, 2:3]
        x0 = max(int(math.floor(uv[:, 0].min())), 0)
        x1 = min(int(math.ceil(uv[:, 0].max())), W - 1)
        y0 = max(int(math.floor(uv[:, 1].min())), 0)
        y1 = min(int(math.ceil(uv[:, 1].max())), H - 1)
        if x1 < x0 or y1 < y0:
            continue
        w, h = x1 - x0 + 1, y1 - y0 + 1
        # Mip level from texels per pixel (area ratio over the clipped polygon).
        th0, tw0 = surf.mips[0].shape
        A = c[1] - c[0]
        B = c[3] - c[0]
        a_len, b_len = np.linalg.norm(A), np.linalg.norm(B)
        # Polygon areas: in the plane (m^2 -> texels) and in the image (px^2).
        pw = poly @ R  # back to world orientation, relative (translation cancels in areas)
        area_w = 0.5 * np.linalg.norm(np.sum(np.cross(pw, np.roll(pw, -1, axis=0)), axis=0))
        area_tex = area_w * (tw0 / a_len) * (th0 / b_len)
        area_img = 0.5 * abs(np.sum(uv[:, 0] * np.roll(uv[:, 1], -1) - uv[:, 1] * np.roll(uv[:, 0], -1)))
        ratio = math.sqrt(area_tex / max(area_img, 1e-9))
        level = int(min(len(surf.mips) - 1, max(0, math.floor(math.log2(max(ratio, 1.0)) + 0.5))))
        tex = surf.mips[level]
        s = 2.0**level
        a_l = A / tw0 * s
        b_l = B / th0 * s
        o_l = c[0] + 0.5 * a_l + 0.5 * b_l
        Hm = K @ np.column_stack([R @ a_l, R @ b_l, R @ o_l + t])
        T = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]])
        patch = cv2.warpPerspective(
            tex, T @ Hm, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
        )
        mask = np.zeros((h, w), np.uint8)
        pts = np.rint((uv - [x0, y0]) * 16).astype(np.int64)
        pts = np.clip(pts, -(1 << 26), 1 << 26).astype(np.int32)
        cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=4)
        # Inverse depth on the plane n.X = d (camera frame): 1/z = (n^T K^-1 [x y 1]) / d.
        n_c = R @ surf.normal_w
        d_c = float(n_c @ pc[0])
        g = (Kinv.T @ n_c) / d_c
        xs = np.arange(x0, x1 + 1, dtype=np.float32)
        ys = np.arange(y0, y1 + 1, dtype=np.float32)
        iz = np.float32(g[0]) * xs[None, :] + np.float32(g[1]) * ys[:, None] + np.float32(g[2])
        zroi = invz[y0 : y1 + 1, x0 : x1 + 1]
        write = (mask > 0) & (iz > zroi)
        np.copyto(img[y0 : y1 + 1, x0 : x1 + 1], patch, where=write)
        np.copyto(zroi, iz, where=write)
    return img, invz
