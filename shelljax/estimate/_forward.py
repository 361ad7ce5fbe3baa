"""Forward models for the simulation-fitted estimators.

A forward model maps the physical unknowns of one session — gauge pressure P_g [Pa], Young's
modulus E [Pa], wall thickness h [m] and local radius R [m] — and the recorded indenter forces F [N] to the predicted
indentation depths |w(0)| [m] at those forces and the predicted wrinkle count n [-], with a flag
saying whether the simulation converged. Estimators only see this interface, so a cheap analytic
law and the axisymmetric shell engine are interchangeable.
"""

from __future__ import annotations

import abc
import math
import dataclasses
import warnings

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._options import FORWARD_MODELS, WRINKLE_LAWS
from ..paper import DEFAULT_POISSON_RATIO, PAPER_KS
from ..physics import IsothermalGas, PolytropicGas, ShellProperties, Similarity, scaling_wrinkle_count


class Prediction(eqx.Module):
    """Output of a forward model: ``depth`` [m] per force, ``wrinkle_count`` [-], ``converged``."""

    depth: Float[Array, " m"]
    wrinkle_count: Float[Array, ""]
    converged: Bool[Array, ""]


class AbstractForwardModel(eqx.Module):
    """F, (P_g, E, h, R) ↦ (|w(0)|, n, converged); must be jit-, vmap- and grad-compatible.

    ``poisson_ratio`` ν [-] is a fixed property of the model (the paper assumes
    ``shelljax.paper.DEFAULT_POISSON_RATIO``).
    """

    poisson_ratio: eqx.AbstractVar[float]

    @abc.abstractmethod
    def __call__(self, gauge_pressure, young_modulus, thickness, radius, forces: Float[Array, " m"]) -> Prediction:
        """Depths [m] at ``forces`` [N] and the wrinkle count for P_g [Pa], E [Pa], h [m], R [m]."""


class ScalingLawModel(AbstractForwardModel):
    """The paper's scaling laws as a forward model: |w(0)| = F / (π k_s R P_g), n = 1.33 τ^½.

    Fitting it reproduces the closed form; it serves as a fast reference and to test estimators.
    ``poisson_ratio`` ν [-], ``k_s`` [-].
    """

    poisson_ratio: float = DEFAULT_POISSON_RATIO
    k_s: float = PAPER_KS

    def __call__(self, gauge_pressure, young_modulus, thickness, radius, forces):
        depth = forces / (jnp.pi * self.k_s * radius * gauge_pressure)
        count = scaling_wrinkle_count(gauge_pressure, radius, young_modulus, thickness, self.poisson_ratio)
        return Prediction(depth=depth, wrinkle_count=count, converged=jnp.array(True))


ENGINE_RADIUS = 0.08  # [m] the engine's radius, the smallest bundled object's (docs: Compilation)


class AxisymForwardModel(AbstractForwardModel):
    """The axisymmetric Neo-Hookean shell engine (``shelljax.axisym``) as a forward model.

    A ball of inflated radius R [m] resting on the ground is poked by a rigid spherical finger of
    radius ``indenter_radius`` a [m] (force control). The curve is solved at ``n_grid`` forces
    evenly spaced over [``force_min``, ``force_max``] [N] and interpolated linearly at the recorded
    forces (the F–w(0) curve is smooth and nearly linear: the interpolation error is far below the
    depth noise; see tests). The wrinkle count is, with ``wrinkle_law = "mechanics"`` (default),
    the engine's mechanical count at the top force, where the protocol records it; with
    ``"scaling"``, Vella et al.'s n = 1.33 τ^½ at the fitted parameters. With a sealed gas it fills
    ``gas_volume_ratio`` [-] times the ball's 4/3 π R³; ``contact_stiffness`` k_c [N/m³] is the
    contact penalty. The engine's gas is the polytropic one, p V^κ constant, with a traced
    ``gas_exponent`` κ [-] (0: the prescribed pressure, 1: the isothermal sealed gas), so both gas
    laws run the same compiled program.

    Every number of a session is a traced field, so one compiled program serves every object:
    the engine (``setup``, static: mesh, solver) runs at ``ENGINE_RADIUS`` R₀ and reaches
    R by exact similarity. Scaling every length by s = R/R₀ at fixed E, P_g scales forces by s²
    and the penalty by 1/s, so w(F; h, a, k_c, R) = s·w(F/s²; h/s, a/s, k_c s, R₀) and
    n(F; h, a, k_c, R) = n(F/s²; h/s, a/s, k_c s, R₀). The finger and the penalty are those of the
    session's measured radius ``reference_radius`` R_m: a fitted R ≠ R_m keeps them at a R/R_m and
    k_c R_m/R (over the few-percent radius uncertainty of a session their effect on w is
    negligible). The engine's static finger radius is R₀: the traced one, always smaller, sets the
    Newton step cap, as a does at R_m.
    """

    poisson_ratio: float
    reference_radius: float
    force_min: float
    force_max: float
    indenter_radius: float
    gas_volume_ratio: float
    contact_stiffness: float
    gas_exponent: float
    n_grid: int = eqx.field(static=True)
    setup: object = eqx.field(static=True)
    wrinkle_law: str = eqx.field(static=True, default="mechanics")

    @classmethod
    def for_forces(
        cls,
        radius: float,
        forces,
        *,
        poisson_ratio: float = DEFAULT_POISSON_RATIO,
        n_grid: int = 7,
        wrinkle_law: str = "mechanics",
        **setup_kwargs,
    ):
        """Model for a session of inflated radius R [m] and recorded ``forces`` [N]; ``setup_kwargs``
        go to the engine's ``Setup`` (its finger, gas law and penalty become traced fields), but for
        ``gas_volume_ratio`` [-] (sealed gas volume / 4/3 π R³, a traced ``CurvePhysics`` field; default 1)."""
        from .._errors import InvalidInputError
        from ..axisym import Setup

        if wrinkle_law not in WRINKLE_LAWS:
            raise InvalidInputError(f"unknown wrinkle_law {wrinkle_law!r}. Fix: use one of {', '.join(WRINKLE_LAWS)}")
        forces = jnp.asarray(forces)
        ratio = setup_kwargs.pop("gas_volume_ratio", 1.0)
        if not (math.isfinite(ratio) and ratio > 0):
            raise InvalidInputError(
                f"gas_volume_ratio = {ratio!r} must be a positive number (sealed gas volume / "
                "4/3 π R³). Fix: pass 1 for a ball"
            )
        given = Setup(radius=float(radius), **setup_kwargs)  # checks every field
        engine = dataclasses.replace(
            given,
            radius=ENGINE_RADIUS,
            indenter_radius=ENGINE_RADIUS,
            contact_stiffness=Setup().contact_stiffness,
            gas=PolytropicGas(),
        )
        gas_exponent = given.gas.exponent
        return cls(
            reference_radius=float(radius),
            force_min=float(forces.min()),
            force_max=float(forces.max()),
            poisson_ratio=poisson_ratio,
            indenter_radius=given.indenter_radius,
            gas_volume_ratio=float(ratio),
            contact_stiffness=given.contact_stiffness,
            gas_exponent=gas_exponent,
            n_grid=n_grid,
            setup=engine,
            wrinkle_law=wrinkle_law,
        )

    def engine_frame(self, radius):
        """(the ``Similarity`` R → R₀, the engine's ``CurvePhysics`` at R₀) of the ball of radius R [m]."""
        from ..axisym import CurvePhysics

        measured = Similarity.between(self.reference_radius, self.setup.radius)
        default = CurvePhysics.defaults(self.setup)
        physics = CurvePhysics(
            indenter_radius=jnp.asarray(measured.length_to_engine(self.indenter_radius), jnp.float64),
            gas_volume_ratio=jnp.asarray(self.gas_volume_ratio, jnp.float64),
            gas_exponent=jnp.asarray(self.gas_exponent, jnp.float64),
            stiffening=default.stiffening,
            areal_weight=default.areal_weight,
            friction_coefficient=default.friction_coefficient,
            contact_stiffness=jnp.asarray(measured.penalty_to_engine(self.contact_stiffness), jnp.float64),
        )
        return Similarity.between(radius, self.setup.radius), physics

    def engine_inputs(self, gauge_pressure, young_modulus, thickness, radius):
        """(the shell at the engine's scale, its curve's forces there (n_grid,) [N], its
        ``CurvePhysics``) of a ball of P_g [Pa], E [Pa], h [m], radius R [m]: the engine's curve
        for these is the model's, by similarity (:meth:`prediction` maps it back)."""
        similarity, physics = self.engine_frame(radius)
        grid = jnp.linspace(self.force_min, self.force_max, self.n_grid)
        shell = ShellProperties(
            gauge_pressure=gauge_pressure,
            young_modulus=young_modulus,
            thickness=similarity.length_to_engine(thickness),
            poisson_ratio=self.poisson_ratio,
        )
        return shell, similarity.force_to_engine(grid), physics

    def prediction(
        self, engine_depth, engine_count, converged, gauge_pressure, young_modulus, thickness, radius, forces
    ) -> Prediction:
        """The prediction at ``forces`` [N] from the engine's curve of :meth:`engine_inputs`:
        its depths (n_grid,) [m] at the engine's scale, its count [-] at the top force and
        whether it converged."""
        grid = jnp.linspace(self.force_min, self.force_max, self.n_grid)
        depth = jnp.interp(forces, grid, Similarity.between(radius, self.setup.radius).length_from_engine(engine_depth))
        if self.wrinkle_law == "mechanics":
            count = engine_count
        else:
            count = ScalingLawModel(self.poisson_ratio)(
                gauge_pressure, young_modulus, thickness, radius, forces
            ).wrinkle_count
        return Prediction(depth=depth, wrinkle_count=count, converged=converged)

    def __call__(self, gauge_pressure, young_modulus, thickness, radius, forces):
        from ..axisym import indentation_curves_raw

        shell, engine_forces, physics = self.engine_inputs(gauge_pressure, young_modulus, thickness, radius)
        curve = indentation_curves_raw(shell, engine_forces, self.setup, physics=physics)
        converged = jnp.all(curve.converged[0])
        return self.prediction(
            curve.w0[0], curve.wrinkle_count[0, -1], converged, gauge_pressure, young_modulus, thickness, radius, forces
        )


def forward_model_for(session, kind: str = "axisym", **options) -> AbstractForwardModel:
    """The forward model ``kind`` ("axisym" or "scaling") set up for ``session``.

    ``options`` go to the axisymmetric engine's Setup (e.g. ``gas=physics.IsothermalGas()``,
    ``n_elements``) or, for "scaling", ``k_s``. With the sealed gas and a session whose mesh
    encloses a volume V [m³], the gas fills V, not the local sphere's 4/3 π R³
    (``gas_volume_ratio`` = V / (4/3 π R³), unless given).
    """
    from .._errors import InvalidInputError

    if kind == "axisym":
        volume = getattr(session, "enclosed_volume", None)
        if isinstance(options.get("gas"), IsothermalGas) and "gas_volume_ratio" not in options:
            if volume is not None:
                options = {**options, "gas_volume_ratio": volume / (4.0 / 3.0 * jnp.pi * session.radius**3)}
            elif getattr(session, "mesh_path", None) is not None:
                warnings.warn(
                    f"{session.source}: the mesh {session.mesh_path} is not watertight, so it encloses no "
                    "volume; the sealed gas fills the local sphere of radius R instead. Fix: close the mesh, "
                    "or pass gas_volume_ratio = V / (4/3 π R³)",
                    stacklevel=2,
                )
        return AxisymForwardModel.for_forces(
            session.radius, session.force, poisson_ratio=session.poisson_ratio, **options
        )
    if kind == "scaling":
        return ScalingLawModel(poisson_ratio=session.poisson_ratio, **options)
    raise InvalidInputError(f"unknown forward model {kind!r}. Fix: use one of {', '.join(FORWARD_MODELS)}")
