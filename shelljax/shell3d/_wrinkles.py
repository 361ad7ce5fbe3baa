"""Radial wrinkles of an indented 3D shell, counted by an angular Fourier analysis.

The shell's normal displacement w = (x − x_ref) · n_ref [m] (n_ref: trimesh's outward vertex
normal of the reference state) is sampled on rings of reference vertices around the indentation
axis. On each ring, w(φ) minus its mean (the axisymmetric dimple) is fitted by least squares with
cos mφ and sin mφ (the vertices are not evenly spaced in φ); the mode amplitude is
√(a_m² + b_m²) [m]. The wrinkle count is the mode with the largest amplitude summed in quadrature
over the rings. Mode 1 (a tilt or sideways shift of the dimple, not a wrinkle) is fitted but not
reported, and modes a ring cannot resolve (fewer than four vertices per wavelength) are left out.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float

from .._errors import InvalidInputError


@dataclasses.dataclass(frozen=True)
class WrinkleSpectrum:
    """Angular spectrum of the normal displacement.

    ``ring_radius`` (k,) [m]: mean reference distance of each ring from the axis; ``modes`` (M,)
    [-]: angular wavenumbers m ≥ 2; ``amplitude`` (k, M) [m] (NaN where a ring cannot resolve m);
    ``count`` [-]: the dominant mode, the wrinkle count; ``count_amplitude`` [m]: its largest
    amplitude over the rings; ``axisymmetric_rms`` [m]: RMS of the ring means (the dimple's size,
    to judge ``count_amplitude`` against).
    """

    ring_radius: np.ndarray
    modes: np.ndarray
    amplitude: np.ndarray
    count: int
    count_amplitude: float
    axisymmetric_rms: float


def wrinkle_spectrum(
    reference: Float[np.ndarray, "V 3"],
    deformed: Float[np.ndarray, "V 3"],
    faces,
    axis_point: Float[np.ndarray, " 3"],
    *,
    max_radius: float,
    ring_width: float,
    max_mode: int = 60,
) -> WrinkleSpectrum:
    """Angular Fourier spectrum of the normal displacement around a vertical indentation axis.

    ``reference``/``deformed`` (V, 3) [m] vertex positions, ``faces`` (F, 3) the triangles,
    ``axis_point`` (3,) [m] a point on the vertical axis (the top vertex). Rings: reference vertices
    on the axis side of the shell (above its mid-height) whose horizontal distance from the axis is
    in [j, j + 1) · ``ring_width`` [m], up to ``max_radius`` [m].
    """
    import trimesh

    ref = np.asarray(reference, float)
    cur = np.asarray(deformed, float)
    tri = np.asarray(faces)
    if ref.shape != cur.shape or ref.ndim != 2 or ref.shape[1] != 3:
        raise InvalidInputError(
            f"reference and deformed must both be (V, 3) arrays in m, got {ref.shape} and {cur.shape}."
        )
    if tri.ndim != 2 or tri.shape[1] != 3 or tri.size == 0 or tri.min() < 0 or tri.max() >= ref.shape[0]:
        raise InvalidInputError(
            f"faces must be an (F, 3) array of vertex indices below {ref.shape[0]}, got shape {tri.shape}."
        )
    if not (ring_width > 0 and max_radius > ring_width):
        raise InvalidInputError(
            f"need 0 < ring_width < max_radius [m], got ring_width={ring_width}, max_radius={max_radius}."
        )
    normals = trimesh.Trimesh(ref, tri, process=False).vertex_normals
    w = np.sum((cur - ref) * normals, axis=1)
    dx, dy = ref[:, 0] - axis_point[0], ref[:, 1] - axis_point[1]
    r, phi = np.hypot(dx, dy), np.arctan2(dy, dx)
    upper = ref[:, 2] > 0.5 * (ref[:, 2].max() + ref[:, 2].min())
    modes = np.arange(2, max_mode + 1)
    radii, amps, means = [], [], []
    for j in range(int(max_radius / ring_width)):
        ring = upper & (r >= j * ring_width) & (r < (j + 1) * ring_width)
        if ring.sum() < 8:
            continue
        resolvable = modes <= ring.sum() // 4
        m = np.concatenate([[1], modes[resolvable]])  # mode 1 fitted so that it does not leak into others
        design = np.concatenate(
            [np.ones((ring.sum(), 1)), np.cos(np.outer(phi[ring], m)), np.sin(np.outer(phi[ring], m))], axis=1
        )
        coef, *_ = np.linalg.lstsq(design, w[ring], rcond=None)
        amp = np.full(modes.size, np.nan)
        amp[resolvable] = np.hypot(coef[2 : 1 + m.size], coef[2 + m.size :])
        radii.append(r[ring].mean())
        amps.append(amp)
        means.append(coef[0])
    if not radii:
        raise InvalidInputError(
            f"no ring of ≥ 8 vertices within {max_radius} m of the axis: raise max_radius or ring_width."
        )
    amplitude = np.array(amps)
    power = np.nansum(amplitude**2, axis=0)
    best = int(np.argmax(power))
    return WrinkleSpectrum(
        ring_radius=np.array(radii),
        modes=modes,
        amplitude=amplitude,
        count=int(modes[best]),
        count_amplitude=float(np.nanmax(amplitude[:, best])),
        axisymmetric_rms=float(np.sqrt(np.mean(np.square(means)))),
    )
