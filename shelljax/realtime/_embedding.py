"""A fine display mesh embedded on a coarser simulation mesh (SI units).

Meshes too fine for real time (a 20k-face scan) are shown while a coarser one (2k faces) is
simulated: each display vertex p is tied, at build time, to its closest point q on the simulation
surface (face f, barycentric weights b) and its offset p − q in that face's orthonormal frame
(t₁ along the face's first edge, n its unit normal, t₂ = n × t₁), divided by the face's length
scale √A_f [m]. Each frame places it at

    p' = Σ bᵢ xᵢ' + √A_f' (c₁ t₁' + c₂ t₂' + c₃ n'),

so a rigid motion of the simulation mesh moves the display mesh rigidly and a uniform scaling
scales it (both exactly, to round-off), and the display mesh is reproduced exactly at the
simulation state it was built on.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._errors import InvalidInputError

__all__ = ["DisplayEmbedding"]


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _face_frame(x, faces, f):
    """Face f's first vertex (3), its frame t₁, t₂, n (3 each) and √(area) [m]."""
    i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
    e1x, e1y, e1z = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]
    e2x, e2y, e2z = x[k, 0] - x[i, 0], x[k, 1] - x[i, 1], x[k, 2] - x[i, 2]
    cx, cy, cz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    cn = math.sqrt(cx * cx + cy * cy + cz * cz)
    nx, ny, nz = cx / cn, cy / cn, cz / cn
    ln = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    t1x, t1y, t1z = e1x / ln, e1y / ln, e1z / ln
    t2x, t2y, t2z = ny * t1z - nz * t1y, nz * t1x - nx * t1z, nx * t1y - ny * t1x
    return t1x, t1y, t1z, t2x, t2y, t2z, nx, ny, nz, math.sqrt(0.5 * cn)


@njit(cache=True, fastmath=False, error_model="numpy")
def _place(x, faces, face, bary, local, out):
    """``out`` (N, 3) [m] ← the display vertices for simulation positions ``x`` (V, 3) [m]."""
    for p in range(face.shape[0]):
        f = face[p]
        t1x, t1y, t1z, t2x, t2y, t2z, nx, ny, nz, s = _face_frame(x, faces, f)
        i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
        b0, b1, b2 = bary[p, 0], bary[p, 1], bary[p, 2]
        c1, c2, c3 = s * local[p, 0], s * local[p, 1], s * local[p, 2]
        for a in range(3):
            t1 = (t1x, t1y, t1z)[a]
            t2 = (t2x, t2y, t2z)[a]
            n = (nx, ny, nz)[a]
            out[p, a] = b0 * x[i, a] + b1 * x[j, a] + b2 * x[k, a] + c1 * t1 + c2 * t2 + c3 * n


def _closest_on_triangles(p, a, b, c):
    """Closest points of points ``p`` (N, 3) on triangles (a, b, c) (N, 3 each) [m], as
    barycentric weights (N, 3) (Ericson, Real-Time Collision Detection, 5.1.5, vectorised)."""
    dot = lambda u, v: np.einsum("ij,ij->i", u, v)
    ab, ac = b - a, c - a
    d1, d2 = dot(ab, p - a), dot(ac, p - a)
    d3, d4 = dot(ab, p - b), dot(ac, p - b)
    d5, d6 = dot(ab, p - c), dot(ac, p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    w = np.zeros((len(p), 3))
    left = np.ones(len(p), dtype=bool)

    def take(mask, w0, w1, w2):
        m = mask & left
        w[m, 0], w[m, 1], w[m, 2] = w0[m], w1[m], w2[m]
        left[m] = False

    zero, one = np.zeros(len(p)), np.ones(len(p))
    with np.errstate(divide="ignore", invalid="ignore"):
        take((d1 <= 0) & (d2 <= 0), one, zero, zero)  # vertex a
        take((d3 >= 0) & (d4 <= d3), zero, one, zero)  # vertex b
        t = d1 / (d1 - d3)
        take((vc <= 0) & (d1 >= 0) & (d3 <= 0), 1 - t, t, zero)  # edge ab
        take((d6 >= 0) & (d5 <= d6), zero, zero, one)  # vertex c
        t = d2 / (d2 - d6)
        take((vb <= 0) & (d2 >= 0) & (d6 <= 0), 1 - t, zero, t)  # edge ac
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        take((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), zero, 1 - t, t)  # edge bc
        denom = va + vb + vc
        take(left, 1 - (vb + vc) / denom, vb / denom, vc / denom)  # the face's interior
    return w


class DisplayEmbedding:
    """A display mesh (``vertices`` (N, 3) [m], optional ``faces`` (M, 3)) embedded on the
    simulation mesh ``simulation_faces`` (F, 3) at its positions ``simulation_positions`` (V, 3)
    [m] (the state the display mesh belongs to, e.g. the inflated scan); see the module docstring.
    ``candidates``: how many nearest simulation faces (by centroid) are searched per display vertex.

    ``positions(x)`` gives the display vertices (N, 3) [m] for simulation positions x (V, 3) [m];
    ``offset_m`` (N,) is each display vertex's distance from the simulation surface at build time.
    """

    def __init__(self, simulation_positions, simulation_faces, vertices, faces=None, candidates=16):
        from scipy.spatial import cKDTree

        x = np.ascontiguousarray(simulation_positions, dtype=float).reshape(-1, 3)
        self.simulation_faces = np.ascontiguousarray(simulation_faces, dtype=np.int64).reshape(-1, 3)
        p = np.asarray(vertices, dtype=float).reshape(-1, 3)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(p))):
            raise InvalidInputError("DisplayEmbedding: positions [m] contain NaN or inf.")
        if self.simulation_faces.size == 0 or self.simulation_faces.max() >= len(x) or self.simulation_faces.min() < 0:
            raise InvalidInputError(f"DisplayEmbedding.simulation_faces: indices must lie in [0, {len(x)}).")
        self.faces = None if faces is None else np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        f = self.simulation_faces
        tri = x[f]
        k = int(min(candidates, len(f)))
        _, near = cKDTree(tri.mean(axis=1)).query(p, k=k)
        near = near.reshape(len(p), k)
        best_d = np.full(len(p), np.inf)
        self.face = np.zeros(len(p), dtype=np.int64)
        self.bary = np.zeros((len(p), 3))
        for c in range(k):  # exact closest points on each candidate face; keep the nearest
            cand = near[:, c]
            w = _closest_on_triangles(p, tri[cand, 0], tri[cand, 1], tri[cand, 2])
            q = np.einsum("ij,ijk->ik", w, tri[cand])
            dist = np.linalg.norm(p - q, axis=1)
            better = dist < best_d
            best_d[better], self.face[better], self.bary[better] = dist[better], cand[better], w[better]
        self.offset_m = best_d
        frames = np.array([_face_frame(x, f, int(i)) for i in range(len(f))])  # (F, 10)
        q = np.einsum("ij,ijk->ik", self.bary, tri[self.face])
        t1, t2, n, s = frames[self.face, 0:3], frames[self.face, 3:6], frames[self.face, 6:9], frames[self.face, 9]
        r = p - q
        self.local = np.ascontiguousarray(
            np.stack([np.einsum("ij,ij->i", r, t1), np.einsum("ij,ij->i", r, t2), np.einsum("ij,ij->i", r, n)], axis=1)
            / s[:, None]
        )

    @property
    def n_vertices(self) -> int:
        return int(self.face.shape[0])

    def positions(self, x, out=None) -> np.ndarray:
        """The display vertices (N, 3) [m] for simulation positions ``x`` (V, 3) [m] (into ``out``)."""
        x = np.ascontiguousarray(x, dtype=float).reshape(-1, 3)
        out = np.empty((self.n_vertices, 3)) if out is None else out
        _place(x, self.simulation_faces, self.face, self.bary, self.local, out)
        return out
