"""femphase: finite-element multi-phase-field simulations of dense soft suspensions in flow."""

__version__ = "0.1.0"
