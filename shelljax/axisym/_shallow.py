"""Point-load checks against shallow-shell theory (Reissner; Vella et al. 2011, 2012).

Set-up: the inflated sphere is pinched by equal and opposite point forces F [N] at its poles
(bottom pole pinned, force on the top pole), no contact. Each pole gets its own dimple, so the
local indentation stiffness of one dimple is k = 2 F / δ with δ the change of pole distance,
as long as the dimples are far apart (l_p, l_b ≪ R).

Analytic references (linear shallow shell, pre-tension T = P_g R / 2, foundation K = E h / R²,
bending B; w(0) = F/(2π) ∫₀^∞ q dq / (B q⁴ + T q² + K) from the Hankel transform):

The closed forms are ``physics.reissner_stiffness`` and ``physics.vella_linear_stiffness``:

* Reissner (P_g = 0): k = 8 √(B K) = 4 E h² / (R √(3 (1 − ν²))).
* Vella et al. 2012 (J. R. Soc. Interface 9, 448): k = 2π √(T² − 4BK) / artanh(√(1 − 4BK/T²)),
  continued analytically (artanh → arctan) for T² < 4BK; with τ = P_g R² / √(E h B) one has
  4BK/T² = 16/τ², so k → Reissner as τ → 0 and k → π P_g R / ln(τ/2) as τ → ∞.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._energy import Config, hoop_tension, rest_nodes, split
from ..physics import PrescribedGas, ShellProperties
from ._model import Setup, _params, _shell, inflate
from ._newton import SolverOptions, equilibrium
from ._observables import compressive_annulus


def pinch_setup(n_elements=201, grading=0.9, radius=0.1):
    """A Setup for pinch checks (no indenter: only its mesh/tolerance fields are used)."""
    return Setup(radius=radius, n_elements=n_elements, grading=grading, relax=False)


def pinch_config(setup: Setup, relax=False) -> Config:
    return Config(theta=setup.theta(), gas=PrescribedGas(), loading="point", ground=False, pin_bottom=True, relax=relax)


def pinch_state(setup: Setup, properties: ShellProperties, force, bending_scale=1.0, guess=None, relax=False):
    """Equilibrium (y [m], inflated y [m], params, residual [N]) of the pole pinch at force F [N]
    of the ball of ``properties`` (scalar P_g, E, h, ν; the radius is ``setup.radius``)."""
    pressure, young, thick, nu = _shell(properties, setup, "pinch_state")
    r0, y_inf, _, _ = inflate(setup, properties, bending_scale)
    cfg = pinch_config(setup, relax)
    p = _params(young, thick, nu, r0, pressure, setup, force=force, bending_scale=bending_scale)
    opts = SolverOptions(setup.atol, 200, 30, 0.05 * setup.radius)
    sol = equilibrium(cfg, opts, p, y_inf if guess is None else guess)
    return sol.value, y_inf, p, sol.stats["residual"]


def pinch_linear_stiffness(setup: Setup, properties: ShellProperties, bending_scale=1.0):
    """Local linear stiffness k = 2 / (dδ/dF) [N/m] at F = 0 of the ball of ``properties``, by
    implicit differentiation."""
    n = len(setup.theta())

    def approach(force):
        y, _, _, _ = pinch_state(setup, properties, force, bending_scale)
        x, _ = split(y, n)
        return x[0, 1] - x[-1, 1]  # minus the pole distance [m]

    dd = jax.jvp(approach, (jnp.asarray(0.0),), (jnp.asarray(1.0),))[1]
    return 2.0 / dd


def pinch_observables(setup: Setup, y, y_inf, p):
    """(w(0) [m] dimple depth of the top pole relative to the equator, min upper hoop tension [N/m],
    compressive annulus (r_in, r_out) [m])."""
    n = len(setup.theta())
    x, _ = split(y, n)
    xi, _ = split(y_inf, n)
    eq = jnp.array([n // 2 - 1, n // 2])
    w0 = (jnp.mean(x[eq, 1]) - jnp.mean(xi[eq, 1])) - (x[-1, 1] - xi[-1, 1])
    n_theta, r_g = hoop_tension(x, rest_nodes(pinch_config(setup), p.rest_radius), p)
    upper = jnp.arange(n_theta.shape[1]) >= n_theta.shape[1] // 2
    return w0, jnp.min(jnp.where(upper, n_theta, jnp.inf)), compressive_annulus(x, n_theta, r_g)


__all__ = ["pinch_config", "pinch_linear_stiffness", "pinch_observables", "pinch_setup", "pinch_state"]
