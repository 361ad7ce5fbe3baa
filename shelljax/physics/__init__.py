"""Physics layer: material, gas, contact and self-weight energies as pure JAX functions, the laws
as objects (the gas laws, :class:`AbstractGasLaw`; the contact laws a :class:`Plane` carries,
:class:`AbstractContactLaw`), the closed-form results of shell theory (SI units), and the one
:class:`ShellProperties` (P_g, E, h, ν, R) the engines and estimators take."""

from ._contact import (
    Plane,
    barrier_energy,
    friction_energy,
    friction_force,
    friction_mollifier,
    penalty_energy,
    plane_gap,
    sphere_gap,
)
from ._contact_laws import (
    AbstractContactLaw,
    BarrierContact,
    CompressionCurve,
    PowerLawContact,
    TabulatedCompressionCurve,
    ground,
)
from ._gas import (
    AIR_HEAT_CAPACITY_RATIO,
    ATMOSPHERIC_PRESSURE,
    GAS_LAWS,
    AbstractGasLaw,
    AdiabaticGas,
    IsothermalGas,
    PolytropicGas,
    PrescribedGas,
    adiabatic_gas_energy,
    adiabatic_gauge_pressure,
    gas_law,
    isothermal_gas_energy,
    isothermal_gauge_pressure,
    polytropic_gas_energy,
    polytropic_gauge_pressure,
    prescribed_pressure_energy,
)
from ._gravity import STANDARD_GRAVITY, areal_weight_from_density, self_weight_energy
from ._material import (
    bending_density,
    bending_density_invariants,
    gent_membrane_invariants,
    gent_shear_energy,
    lame_constants_2d,
    neo_hookean_membrane_density,
    neo_hookean_membrane_invariants,
)
from ._properties import ShellProperties
from ._similarity import Similarity
from ._shell_theory import (
    CRITICAL_W,
    WRINKLE_PREFACTOR,
    bending_stiffness,
    reissner_stiffness,
    scaling_wrinkle_count,
    tau,
    vella_linear_stiffness,
)
