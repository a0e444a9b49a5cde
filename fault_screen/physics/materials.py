"""Material laws of the porous rock: the drained moduli and the Biot storage that every term,
the leak-off grading and the size estimate read (one copy of each formula).

Poroelastic constants follow Biot's theory as used by the paper (Eq. 1-2): K = E / (3 (1 - 2 nu))
the drained bulk modulus, Ks = K / (1 - alpha) the grain bulk modulus when none is given (so that
alpha = 1 - K/Ks), 1/M = (alpha - n)/Ks + n/Kf the inverse Biot modulus, and the constrained
(oedometric) modulus K + 4G/3 = E (1 - nu) / ((1 + nu)(1 - 2 nu)) of uniaxial strain.
"""
from __future__ import annotations

import numpy as np


def drained_bulk_modulus(youngs_modulus: float, poissons_ratio: float) -> float:
    """K = E / (3 (1 - 2 nu)) (Pa)."""
    return youngs_modulus / (3.0 * (1.0 - 2.0 * poissons_ratio))


def constrained_modulus(youngs_modulus: float, poissons_ratio: float) -> float:
    """K + 4G/3 = E (1 - nu) / ((1 + nu)(1 - 2 nu)) (Pa): stiffness of uniaxial strain."""
    nu = poissons_ratio
    return youngs_modulus * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))


def effective_rock(spec, fluid_bulk_modulus: float, viscosity: float) -> dict:
    """Derived constants of a ``scene.RockSpec`` in SI: E, nu, alpha, mobility k/mu, 1/M (Biot
    modulus), Ks."""
    E, nu, alpha, n = spec.youngs_modulus, spec.poissons_ratio, spec.biot_coefficient, spec.porosity
    K = drained_bulk_modulus(E, nu)
    Ks = spec.solid_bulk_modulus
    if Ks is None:
        Ks = K / (1.0 - alpha) if alpha < 1.0 else np.inf
    inv_M = (alpha - n) / Ks + n / fluid_bulk_modulus
    return {"E": E, "nu": nu, "alpha": alpha, "mobility": spec.mobility_at(viscosity),
            "inv_M": inv_M, "Ks": Ks}


def storage_coefficient(props: dict, mechanics: bool) -> float:
    """Uniaxial-strain storage S = 1/M + alpha^2 / (K + 4G/3) (1/Pa) of ``effective_rock``
    props; 1/M alone in rigid rock (``mechanics`` off)."""
    if not mechanics:
        return props["inv_M"]
    return props["inv_M"] + props["alpha"] ** 2 / constrained_modulus(props["E"], props["nu"])


def diffusivity(props: dict, mechanics: bool) -> float:
    """Hydraulic diffusivity c = (k/mu) / S (m^2/s) of ``effective_rock`` props."""
    return props["mobility"] / storage_coefficient(props, mechanics)
