"""Leak-off resolved across the fault: the mesh is graded normal to the fault (issue 10).

Fluid leaks from the fault into each wall by diffusion normal to it,
dp/dt = c d2p/dz2 with the diffusivity c = (k/mu) / S (m^2/s) and the uniaxial-strain storage
S = 1/M + alpha^2 / (K + 4G/3) (1/Pa; 1/M alone without mechanics). After a time t it has reached
about sqrt(c t) (m) into the rock; at a constant overpressure dp a wall has taken
2 dp S sqrt(c t / pi) per unit area of fault.

The fault pressure is the trace of the rock pressure (modified-level-set enrichment). On a mesh
whose elements across the fault are much taller than sqrt(c t), that trace is tied to the storage
of the cut elements -- a strip about half an element high on each side -- so the fault stores and
leaks as that strip does and the result depends on the element height instead of the physics.
This term grades the node lines across a fault that runs along x or y so that the cut element is
``size = 0.5 sqrt(c dt)`` high (``mesh.fault_grading_size`` overrides), with dt the first time step:
the shortest diffusion length the implicit steps resolve, so finer elements would buy nothing. The
heights grow by ``mesh.fault_grading_growth`` away from the fault up to those of the given mesh.
c is that of the most slowly diffusing permeable rock along the fault (the rock, or the last band
zone such as the damage zone, and the box zones the fault passes through).

Limitation: a structured mesh can only be graded along x or y. A fault at another angle keeps
the mesh as given; when its elements are taller across the fault than 4 sqrt(c dt) a SceneWarning
says so (refine with ``[mesh.refinement]`` or rotate the model so that the fault lies along x).
"""
from __future__ import annotations

import warnings

import numpy as np

from ..mesh import StructuredMesh, grade_across
from .base import Term
from .materials import diffusivity, effective_rock

#: cut-element height over the first step's leak-off length sqrt(c dt): the leaked volume is then
#: within 2 % of the erfc solution once the first steps' time error has decayed (from the 20th
#: step, tests/physics/test_leak_off_mesh.py; after one step it is the implicit step's own -11 %)
SIZE_FRACTION = 0.5
#: a mesh whose cut elements are taller than this many sqrt(c dt) across a fault that cannot be
#: graded gets a warning
WARN_RATIO = 4.0


def fault_axis(angle_deg: float) -> int | None:
    """0 for a fault along x, 1 along y, None at any other angle."""
    a = angle_deg % 180.0
    if min(a, 180.0 - a) < 1e-9:
        return 0
    if abs(a - 90.0) < 1e-9:
        return 1
    return None


class LeakOffGrading(Term):
    """Grading of the mesh normal to a fault with leak-off (see the module docstring)."""

    def __init__(self, scene, mechanics: bool):
        self.enabled = scene.mesh.fault_grading == "auto"
        self.mechanics = mechanics
        self.growth = scene.mesh.fault_grading_growth
        self.size_given = scene.mesh.fault_grading_size

    def leak_off_length(self, scene, zones) -> float:
        """sqrt(c dt) of the first step (m) in the most slowly diffusing permeable rock the
        fault crosses; 0 when none is permeable."""
        p = np.asarray(scene.fault_point, dtype=float)
        a = np.radians(scene.fault.angle)
        n = np.array([-np.sin(a), np.cos(a)])
        specs = [scene.rock]
        for z in zones:  # in the order they are applied: a later zone overrides an earlier one
            if z.band is not None:
                specs = [scene.rock.with_overrides(z.rock)]  # a band holds the whole fault
                continue
            x0, x1, y0, y1 = z.box
            phi = (np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]) - p) @ n
            if phi.min() <= 0 <= phi.max():  # the fault passes through the box
                specs.append(scene.rock.with_overrides(z.rock))
        c = []
        for spec in specs:
            props = effective_rock(spec, scene.fluid.bulk_modulus, scene.fluid.viscosity)
            if props["mobility"] > 0:
                c.append(diffusivity(props, self.mechanics))
        return float(np.sqrt(min(c) * scene.time.dt)) if c else 0.0

    def target_size(self, scene, zones) -> float:
        """Height of the cut element the grading aims at (m); 0: nothing to resolve."""
        if self.size_given is not None:
            return self.size_given
        return SIZE_FRACTION * self.leak_off_length(scene, zones)

    def cut_height(self, scene, zones) -> float:
        """Height across the fault of the element the grading makes the fault cut (m); 0 when
        it grades nothing (grading off, a fault at an angle, impermeable rock)."""
        if not self.enabled or fault_axis(scene.fault.angle) is None:
            return 0.0
        return self.target_size(scene, zones)

    def refine_mesh(self, scene, mesh: StructuredMesh, zones) -> StructuredMesh:
        axis = fault_axis(scene.fault.angle)
        size = self.cut_height(scene, zones)
        if size <= 0:
            return mesh
        at = scene.fault_point[1 - axis]
        if axis == 0:
            return StructuredMesh(mesh.x_lines, grade_across(mesh.y_lines, at, size, self.growth))
        return StructuredMesh(grade_across(mesh.x_lines, at, size, self.growth), mesh.y_lines)

    def check(self, disc):
        """Warn when the elements across the fault stay much taller than the leak-off length."""
        scene = disc.scene
        length = self.leak_off_length(scene, disc.physics.zones(scene) + tuple(scene.zones))
        if length <= 0 or not len(disc.cut_elements):
            return
        hx, hy = disc.mesh.element_sizes[disc.cut_elements].T
        n = disc.fault.normal
        height = float(np.max(np.abs(n[0]) * hx + np.abs(n[1]) * hy))  # extent across the fault
        if height <= WARN_RATIO * length:
            return
        from ..scene import SceneWarning

        if not self.enabled:
            why = "mesh.fault_grading = 'off'"
        elif fault_axis(scene.fault.angle) is None:
            why = (f"the fault (fault.angle = {scene.fault.angle:g}) does not run along x or y, so the "
                   f"mesh cannot be graded across it")
        else:
            why = f"mesh.fault_grading_size = {self.size_given:g} m"
        warnings.warn(
            f"leak-off: the elements the fault cuts are up to {height:.3g} m across it, "
            f"{height / length:.3g} times the leak-off length sqrt(c dt) = {length:.3g} m of the first "
            f"step, and {why}: the fault pressure is tied to the rock storage of the cut elements and "
            f"results depend on the element height across the fault (docs/verification.md, 'Leak-off and mesh'); "
            f"refine with [mesh.refinement] or lay the fault along x", SceneWarning, stacklevel=2)
