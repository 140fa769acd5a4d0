"""The energy audit of a simulated impact: where the impact energy went.

Every term comes from the forward simulation (integrated works and the state's
energies), so the balance error measures the physics and the integrator, not
an NLP. Where a form's impact is an impulse (the pendulum's pivot, which keeps
the angular momentum about it and stops the tangential velocity), the kinetic
energy it takes is `impact_loss`; a form without one (rigid-body) has none. The front end is the
only barrier force (engine-on-mounts' engine, which meets the barrier too, counts its contact with
the front end's terms and its mounts' damper with the suspension's), so the
barrier's work on the vehicle is minus what the front end absorbs; a rigid
barrier supplies no energy, so the front end may give back at most what it
stores (`front_end_returned_excess` is the largest excess, ~0).
"""

from __future__ import annotations

import numpy as np

from crashnlp.results.response import Response


def energy_audit(response: Response, mass: float, speed: float) -> dict[str, float]:
    """Energy terms in J of one simulated test (a Response with the ABSORBED works)."""
    y = response.outputs
    kinetic, stored = y["kinetic"], y["front_energy"]
    potential = y["potential"] - stored  # gravity and suspension springs
    impact = 0.5 * mass * speed**2
    spring = y["front_work"] - y["front_damper_work"]
    terms = {
        "impact_kinetic": impact,
        "impact_loss": impact - float(kinetic[0]),
        "front_end_spring": float(spring[-1]),
        "front_end_damper": float(y["front_damper_work"][-1]),
        "front_end_stored_at_end": float(stored[-1]),
        "suspension_damping": float(y["suspension_work"][-1]),
        "barrier_work_on_vehicle": -float(y["front_work"][-1]),
        "final_kinetic": float(kinetic[-1]),
        "final_potential_change": float(potential[-1] - potential[0]),
        "front_end_returned_excess": float(max(0.0, np.max(stored - y["front_work"]))),
    }
    spent = (
        terms["impact_loss"]
        + terms["front_end_spring"]
        + terms["front_end_damper"]
        + terms["suspension_damping"]
        + terms["final_kinetic"]
        + terms["final_potential_change"]
    )
    terms["balance_error"] = impact - spent
    terms["balance_error_relative"] = terms["balance_error"] / impact
    return terms
