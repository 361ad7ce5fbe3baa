"""A 12-node spring balloon with sealed gas, swung by a clamped patch into a wall (the hammer's
scenario in miniature): prescribed motion, barrier contact with friction and damping, gas, output.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from shelljax import NoConvergenceError
from shelljax import dynamics as d
from shelljax.geometry import sphere_mesh

pytestmark = pytest.mark.slow  # dynamics runs of the spring balloon

RADIUS, CENTRE_HEIGHT = 0.05, 0.15  # [m]


def swing_system(wall_x=0.16):
    nodes, faces = sphere_mesh(RADIUS, layout="icosphere", subdivisions=0)
    nodes = nodes + np.array([0.0, 0.0, CENTRE_HEIGHT])
    lowest = int(np.argmin(nodes[:, 2]))
    clamp = np.unique(faces[np.any(faces == lowest, axis=1)])  # the lowest node and its ring
    schedule = d.PrescribedRotation(
        nodes[clamp], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.04, 0.12], np.radians([0.0, -30.0, 60.0])
    )
    wall = d.Plane(
        [wall_x, 0.0, 0.0], [-1.0, 0.0, 0.0], d.BarrierContact(2e-3, 1e3), friction=0.3, damping=0.2, name="wall"
    )
    system = d.SpringBalloon(
        nodes,
        faces,
        0.01,
        2000.0,
        [wall],
        gauge_pressure=0.0,
        gas_exponent=1.4,
        prescribed_nodes=tuple(int(i) for i in clamp),
        prescribed=schedule,
    )
    return system, nodes, clamp, schedule


def test_swing_into_a_wall_follows_the_schedule_and_squeezes_the_gas(tmp_path):
    system, nodes, clamp, schedule = swing_system()
    trajectory = d.simulate(system, d.initial_state(system, nodes), 5e-4, 0.15, progress=False)
    positions = trajectory["position_m"].reshape(len(trajectory["time_s"]), -1, 3)
    expected = np.stack([np.asarray(schedule.positions(t)) for t in trajectory["time_s"]])
    np.testing.assert_allclose(positions[:, clamp], expected, atol=1e-14)  # prescribed exactly
    assert trajectory["min_gap_m"].min() > 0.0  # the barrier kept every node off the wall
    (impact, *_) = d.measured_cor(trajectory)
    assert impact.plane == "wall" and impact.peak_force_N > 10.0
    pressure = trajectory["gas_pressure_Pa"]
    peak = int(np.argmax(pressure))
    # The adiabatic gas peaks while the wall pushes (measured 6.8 kPa), well above the swing's own
    # squeeze before the first contact (2.5 kPa).
    assert trajectory["contact_force_N"][peak, 0] @ np.array([-1.0, 0.0, 0.0]) > 1.0
    assert pressure[peak] > 2.0 * pressure[trajectory["time_s"] < impact.onset_s].max()
    written = d.write_results(trajectory, tmp_path, max_frames=4, mesh_format="glb")
    assert (tmp_path / "preview.gif").exists() and len(list((tmp_path / "frames").glob("*.glb"))) == 4
    import trimesh

    frame = trimesh.load(tmp_path / "frames" / "frame_0003.glb", force="mesh")
    assert len(frame.faces) == 20  # the icosahedron, loadable by common tools
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["summary"]["impacts"][0]["plane"] == "wall" and all(p.exists() for p in written)


def test_prescribed_nodes_pushed_through_a_barrier_plane_are_reported():
    system, nodes, _, _ = swing_system(wall_x=0.12)  # the clamp itself reaches x = 0.128 m at 60°
    with pytest.raises(NoConvergenceError, match="prescribed motion pushes nodes into a plane"):
        d.simulate(system, d.initial_state(system, nodes), 5e-4, 0.15, progress=False)


def test_point_hessian_blocks_assemble_the_dense_hessian():
    # The decomposition a sparse minimiser uses: inertia + internal energy's Hessian + point blocks.
    import jax
    import jax.numpy as jnp

    nodes0, _ = sphere_mesh(RADIUS, layout="icosphere", subdivisions=0)
    system, nodes, clamp, _ = swing_system(wall_x=float(nodes0[:, 0].max()) + 1e-3)  # nodes 1 mm inside ĝ = 2 mm
    state = d.initial_state(system, nodes, np.tile([0.3, 0.0, 0.1], len(nodes)))
    potential = d.incremental_potential(system, d.Newmark(), state, 1e-3)
    x = jnp.asarray(nodes.reshape(-1)) + 1e-4
    x = x.at[potential.prescribed_dofs].set(potential.prescribed_values)
    import equinox as eqx

    @eqx.filter_jit
    def hessians(potential, x):
        assembled = jnp.diag(potential.inertia_weight) + jax.hessian(potential.system.internal_energy)(
            x, potential.time
        )
        blocks = potential.point_hessian_blocks(x)
        assembled = assembled + jax.scipy.linalg.block_diag(*blocks)
        return blocks, assembled, potential.dense_hessian(potential.free(x))

    blocks, assembled, dense = hessians(potential, x)
    assert float(jnp.max(jnp.abs(blocks))) > 0.0
    n = x.shape[0]
    free = np.asarray(potential.free_dofs)
    np.testing.assert_allclose(
        dense, assembled[np.ix_(free, free)], rtol=1e-10, atol=1e-8 * float(jnp.max(jnp.abs(dense)))
    )
    assert n == 3 * len(nodes)
