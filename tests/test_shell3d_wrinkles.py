"""Angular Fourier wrinkle count of the 3D engine (shelljax.shell3d.wrinkle_spectrum).

Checked on meshes deformed by a prescribed field, so the true mode and amplitude are known
exactly; no shell solve.
"""

import numpy as np
import pytest

import shelljax.shell3d as s3
from shelljax import InvalidInputError

pytestmark = pytest.mark.slow  # solves the 3D shell

RADIUS = 0.13  # m


@pytest.fixture(scope="module")
def sphere():
    return s3.ball(RADIUS, 1e-3, 12000, pole_refinement=6).mesh


def _deform(mesh, mode, amplitude, dimple=0.02, tilt=0.0):
    """An axisymmetric dimple of depth ``dimple`` [m] plus ``amplitude`` [m] · cos(mode φ) on a
    ring 40–80 mm from the top, both along the sphere's normal."""
    v = np.asarray(mesh.vertices)
    centre = 0.5 * (v.max(0) + v.min(0))
    normal = (v - centre) / np.linalg.norm(v - centre, axis=1, keepdims=True)
    top = int(np.argmax(v[:, 2]))
    r = np.hypot(v[:, 0] - v[top, 0], v[:, 1] - v[top, 1])
    phi = np.arctan2(v[:, 1] - v[top, 1], v[:, 0] - v[top, 0])
    upper = v[:, 2] > centre[2]
    w = -dimple * np.exp(-((r / 0.04) ** 2)) * upper
    band = upper * np.clip(np.sin(np.pi * (r - 0.04) / 0.04), 0.0, None) * ((r > 0.04) & (r < 0.08))
    w = w + amplitude * band * np.cos(mode * phi + 0.3) + tilt * upper * r * np.cos(phi)
    return v, v + w[:, None] * normal, top


@pytest.mark.parametrize("mode", [4, 9, 14])
def test_prescribed_wrinkles_are_counted_with_their_amplitude(sphere, mode):
    ref, cur, top = _deform(sphere, mode, amplitude=1e-3, tilt=0.02)
    spec = s3.wrinkle_spectrum(ref, cur, sphere.faces, ref[top], max_radius=0.1, ring_width=0.005)
    assert spec.count == mode
    # The field's peak amplitude is 1 mm at r = 60 mm; rings 5 mm wide average sin(π(r − 40)/40)
    # over their width, and the vertex normals differ from the exact sphere normal by O(edge/R)
    # (edges ≈ 5 mm: < 0.2 % in the projection). 3 % covers both.
    # A tilt of the whole dimple (mode 1) is fitted separately and must not leak into the count.
    assert spec.count_amplitude == pytest.approx(1e-3, rel=0.03)
    # The dimple itself (20 mm deep) is removed as each ring's mean, not reported as a mode.
    assert spec.axisymmetric_rms > 1e-3


def test_an_axisymmetric_dimple_has_no_wrinkle_mode(sphere):
    ref, cur, top = _deform(sphere, 6, amplitude=0.0)
    spec = s3.wrinkle_spectrum(ref, cur, sphere.faces, ref[top], max_radius=0.1, ring_width=0.005)
    # What remains is the mesh's irregularity times the dimple's radial slope inside a ring:
    # under 2 % of the 20 mm dimple, and far below any wrinkle a reader would count (≥ 0.1 mm).
    assert np.nanmax(spec.amplitude) < 0.02 * 0.02


def test_bad_rings_raise_clear_errors(sphere):
    v = np.asarray(sphere.vertices)
    with pytest.raises(InvalidInputError, match="ring_width"):
        s3.wrinkle_spectrum(v, v, sphere.faces, v[0], max_radius=0.01, ring_width=0.02)
    with pytest.raises(InvalidInputError, match=r"\(V, 3\)"):
        s3.wrinkle_spectrum(v, v[:-1], sphere.faces, v[0], max_radius=0.1, ring_width=0.005)
    with pytest.raises(InvalidInputError, match="faces"):
        s3.wrinkle_spectrum(v, v, np.asarray(sphere.faces) + len(v), v[0], max_radius=0.1, ring_width=0.005)
