"""The predictor of the second-order step under flow, and what it costs in accuracy (session 7).

    python benchmarks/predictors.py              # sav2 at fixed dt = 2.5 and 5
    python benchmarks/predictors.py --adaptive   # the adaptive scheme (outer step 10) with each

sav2's flow step evaluates the explicit forces g at a midpoint φ̄ predicted by one linearly
implicit Euler step of dt/2 whose stabilisation S = max(0, L/2 − 2/(J0 dt)) (L: the
worst-case curvature bound of the explicit energy) keeps it energy-stable. For dt above ~1.8
that S is active everywhere, and it slows the predicted relaxation. This compares, on the
lattice protocol of ``work_precision.py --schemes`` (relax 300, shear 3600 at γ̇ = 0.1487,
errors in time against sav2 at dt = 0.25), sav2 at fixed dt = 2.5 and 5 (the adaptive
scheme's substeps at its default outer step 10) with predictors registered as schemes of
this process only:

* ``S × k``: the default predictor with its stabilisation scaled by k (0: none);
* ``fitted``: a Lie-split predictor, a pointwise reaction half step
  φ̃ = φ⁰ − (dt/2) J0 g(φ⁰)/(1 + σ) then an implicit diffusion half step
  (2M/dt + J0 D K) φ̄ = 2M/dt φ̃, with σ per node fitted so that the step integrates the
  frozen local linearisation exactly: 1 − z + z²/(2(1 + σ)) = e^{−z}, z = J0 dt c and
  c = ∂g_i/∂φ_i at the node (double well, repulsion, the area term's local part; its
  rank-one part is left out).

With ``--adaptive``: the default adaptive scheme against the same with the fitted predictor
(``adaptive_fitted``) at three tolerances, on the same protocol. Prints the errors and CPU
seconds per run; benchmarks/README.md ("Tried in session 7") has
the numbers of session 7.
"""

from __future__ import annotations

import argparse

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np

import work_precision as wp
from femphase.energy import WindowedFields
from femphase.schemes import AdaptiveSAV2, RelaxedSAV2
from femphase.stepping import SCHEMES

SCALES = (0.5, 0.0)
STEPS = (2.5, 5.0)


def scaled_predictor(scale: float) -> str:
    """Register sav2 with its flow predictor's stabilisation × ``scale``; its scheme name."""
    name = f"sav2_predictor_{scale:g}"

    class Scaled(RelaxedSAV2):
        def predictor_stabilisation(self, dt: float) -> float:
            full = super().predictor_stabilisation(dt)
            return full if self.stepper.flow.is_still else scale * full

    Scaled.name = name
    SCHEMES.register(name)(Scaled)
    return name


def fitted_denominator(z: np.ndarray) -> np.ndarray:
    """1 + σ with 1 − z + z²/(2(1 + σ)) = e^{−z} (series near z = 0)."""
    out = np.empty_like(z)
    small = np.abs(z) < 1e-3
    out[small] = 1.0 / (1.0 - z[small] / 3.0 + z[small] ** 2 / 12.0)
    large = z[~small]
    out[~small] = large**2 / (2.0 * (np.expm1(-large) + large))
    return out


def local_curvature(params, fields: WindowedFields) -> np.ndarray:
    """∂g_i/∂φ_i at every node without the area term's rank-one part."""
    lam, phi = params.interface_width, fields.phi
    area = 4.0 * params.area_stiffness / (np.pi * fields.radius**2) * (1.0 - fields.area_ratio)
    return (params.tension / lam * 8.0 * (1.0 - 6.0 * phi + 6.0 * phi**2)
            + 4.0 * params.repulsion / lam * fields.others_squared - fields.on_positions(area))


@SCHEMES.register("sav2_fitted")
class FittedPredictor(RelaxedSAV2):
    """sav2 with the Lie-split, exponentially fitted flow predictor (module docstring)."""

    name = "sav2_fitted"

    def relax(self, phi, layout, time, radii, r, dt, **decays):
        # session 7's predictor, from before the repulsion split: it runs unsplit (main)
        assert not self.decaying, "the fitted predictor needs numerics.repulsion_split = false"
        if r is not None:
            return super().relax(phi, layout, time, radii, r, dt)
        stepper, j0 = self.stepper, self.stepper.mobility
        fields = WindowedFields(phi, layout, radii)
        g = stepper.energy.explicit_derivative(fields)
        reacted = phi - (0.5 * dt * j0) * g / fitted_denominator(j0 * dt * local_curvature(stepper.params, fields))
        midpoint = stepper.solve(np.zeros_like(phi), reacted, layout, 2.0 / dt, 0.0)
        g = stepper.energy.explicit_derivative(WindowedFields(midpoint, layout, radii))
        new = stepper.solve(-2.0 * j0 * g, 2.0 * phi, layout, 2.0 / dt, 0.0)
        new -= phi
        return new, None, float(np.max(np.abs(new - 2.0 * midpoint + phi)))


@SCHEMES.register("adaptive_fitted")
class AdaptiveFitted(FittedPredictor, AdaptiveSAV2):
    """The adaptive scheme with the fitted predictor."""

    name = "adaptive_fitted"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--adaptive", action="store_true", help="the adaptive scheme with each predictor")
    args = parser.parse_args()
    reference = wp.run(wp.Point("lattice", "fem", 1.0, 0.25, {"scheme": "sav2"}))
    if args.adaptive:
        runs = [("energy-stable S (the default), tolerance_t 0.01", 10.0, {"scheme": "adaptive"})]
        runs += [(f"fitted, tolerance_t {tol:g}", 10.0, {"scheme": "adaptive_fitted", "tolerance_t": tol,
                                                                        "repulsion_split": False})
                 for tol in (1e-2, 2e-2, 3e-2)]
    else:
        schemes = [("energy-stable S (sav2, the default's)", "sav2")]
        schemes += [(f"S × {scale:g}", scaled_predictor(scale)) for scale in SCALES]
        schemes += [("fitted, Lie-split", "sav2_fitted")]
        runs = [(label, dt, {"scheme": scheme, **({"repulsion_split": False} if "fitted" in scheme else {})})
                for label, scheme in schemes for dt in STEPS]
    print("| predictor | dt | CPU s | r(t), in time | period, in time |\n|---|---|---|---|---|")
    for label, dt, options in runs:
        point = wp.run(wp.Point("lattice", "fem", 1.0, dt, options))
        if point.failure:
            print(f"| {label} | {dt:g} | – | {point.failure.split(':')[0]} | |", flush=True)
            continue
        errors = wp.lattice_errors(point, reference.result)
        print(f"| {label} | {dt:g} | {point.seconds:.1f} | {100 * errors['elongation']:.2f} % | "
              f"{100 * errors['period']:.3f} % |", flush=True)


if __name__ == "__main__":
    main()
