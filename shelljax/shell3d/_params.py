"""The differentiable parameters of a shell model (traced arrays, SI units)."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._errors import InvalidInputError
from ..physics import ATMOSPHERIC_PRESSURE, ShellProperties


def _array(value):
    return None if value is None else jnp.asarray(value)


#: The lagged friction entries of :class:`ShellParams`.
FRICTION_FIELDS = ("friction_anchor", "friction_normal_force", "friction_coefficient")


class ShellParams(eqx.Module):
    """Parameters of one solve, the values a :class:`ShellModel` can be differentiated against.

    ``young_modulus`` E [Pa], ``poisson_ratio`` ν [-], ``thickness`` h [m], ``gauge_pressure`` P_g
    [Pa] (prescribed, or the sealed gas's gauge pressure at ``reference_volume`` [m³], with
    ``atmospheric_pressure`` [Pa] outside), ``indenter_center`` (3,) [m], ``indenter_force`` [N]
    (force control). Optional (None: absent): ``nodal_forces`` (V, 3) [N], ``mass`` [kg] (gravity);
    with friction (μ > 0 and planes) ``friction_anchor`` (V, 3) [m] (lagged vertex positions, the
    origin of the slip), ``friction_normal_force`` (n_planes, V) [N] (lagged normal contact force of
    every vertex on every plane) and ``friction_coefficient`` μ [-], which overrides the config's μ
    (differentiable; :meth:`ShellModel.host_params` sets it, so that models differing only in μ > 0
    share one compilation). An absent entry changes the pytree, hence the compiled functions' key.
    Every entry is keyword-only; :meth:`of` builds the parameters from a
    :class:`shelljax.physics.ShellProperties`.
    """

    young_modulus: Float[Array, ""] = eqx.field(converter=jnp.asarray, kw_only=True)
    poisson_ratio: Float[Array, ""] = eqx.field(converter=jnp.asarray, kw_only=True)
    thickness: Float[Array, ""] = eqx.field(converter=jnp.asarray, kw_only=True)
    gauge_pressure: Float[Array, ""] = eqx.field(converter=jnp.asarray, kw_only=True)
    indenter_center: Float[Array, " 3"] = eqx.field(converter=jnp.asarray, default_factory=lambda: jnp.zeros(3))
    indenter_force: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=0.0)
    reference_volume: Float[Array, ""] | None = eqx.field(converter=_array, default=None)
    atmospheric_pressure: Float[Array, ""] | None = eqx.field(converter=_array, default=None)
    nodal_forces: Float[Array, "V 3"] | None = eqx.field(converter=_array, default=None)
    mass: Float[Array, ""] | None = eqx.field(converter=_array, default=None)
    friction_anchor: Float[Array, "V 3"] | None = eqx.field(converter=_array, default=None)
    friction_normal_force: Float[Array, "P V"] | None = eqx.field(converter=_array, default=None)
    friction_coefficient: Float[Array, ""] | None = eqx.field(converter=_array, default=None)

    @classmethod
    def of(cls, properties: ShellProperties, **extra) -> "ShellParams":
        """The parameters of ``properties`` (scalar P_g [Pa], E [Pa], h [m], ν [-]; its radius is
        not read: the mesh is the geometry) and the ``extra`` entries."""
        if not isinstance(properties, ShellProperties):
            raise InvalidInputError(
                f"expected a physics.ShellProperties, got {type(properties).__name__}. Fix: "
                "ShellProperties(gauge_pressure=…, young_modulus=…, thickness=…, poisson_ratio=…)"
            )
        return cls(
            young_modulus=properties.young_modulus,
            poisson_ratio=properties.poisson_ratio,
            thickness=properties.thickness,
            gauge_pressure=properties.gauge_pressure,
            **extra,
        )

    @property
    def outside_pressure(self) -> Float[Array, ""]:
        """Atmospheric pressure [Pa] around a sealed gas (the standard one unless set)."""
        return ATMOSPHERIC_PRESSURE if self.atmospheric_pressure is None else self.atmospheric_pressure

    def replace(self, **changes) -> "ShellParams":
        """A copy with the named entries replaced (values converted to arrays)."""
        return dataclasses.replace(self, **changes)
