"""Closed-form impact references for checking simulated impacts (SI units).

* Hertz: a mass m [kg] at speed v [m/s] onto a contact F = K δ^{3/2} (K [N/m^1.5]) reaches
  δ_max = (5 m v² / (4 K))^{2/5} [m] and F_max = K δ_max^{3/2} [N], and stays in contact for
  t_c = 2.9433 δ_max / v [s] (no gravity during contact; Johnson, Contact Mechanics, Sec. 11.4).
* the textbook pressurized ball: a membrane ball of radius R [m] at gauge pressure P_g [Pa] pressed
  by δ flattens a cap of area ≈ 2πRδ, so F ≈ 2πR P_g δ: a linear spring k = 2πR P_g [N/m] with
  contact time π √(m / k) [s]. It neglects the wall's stiffness and the gas's compression.
"""

from __future__ import annotations

import math

# t_c v / δ_max = 2 ∫₀¹ du / √(1 − u^{5/2}) for the Hertz law (scipy quad: 2.943275184).
_HERTZ_TIME_FACTOR = 2.943275184


def hertz_impact(mass: float, speed: float, stiffness: float) -> dict[str, float]:
    """Hertz impact of ``mass`` [kg] at ``speed`` [m/s] on F = K δ^1.5 (K = ``stiffness`` [N/m^1.5])."""
    compression = (5.0 * mass * speed**2 / (4.0 * stiffness)) ** 0.4
    return {
        "max_compression_m": compression,
        "peak_force_N": stiffness * compression**1.5,
        "contact_time_s": _HERTZ_TIME_FACTOR * compression / speed,
    }


def pressurized_ball_stiffness(radius: float, gauge_pressure: float) -> float:
    """Contact stiffness k ≈ 2π R P_g [N/m] of a membrane ball of radius R [m] at gauge pressure P_g [Pa]."""
    return 2.0 * math.pi * radius * gauge_pressure


def pressurized_ball_contact_time(mass: float, radius: float, gauge_pressure: float) -> float:
    """Contact time π √(m / (2π R P_g)) [s] of a ball of mass m [kg], radius R [m], gauge pressure P_g [Pa]."""
    return math.pi * math.sqrt(mass / pressurized_ball_stiffness(radius, gauge_pressure))
