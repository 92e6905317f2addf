"""Stage 1: the spot density from the orifice.

* :mod:`~spotpde.density.orifice`: the injection profile ``S`` on the floor and ``Q0(t)``;
* :mod:`~spotpde.density.spot_density`: ``rho_s``, steady (height as time) and transient;
* :mod:`~spotpde.density.kinematic`: the Kinematic Model for the same orifice and ``b``.

Private modules hold the solvers of ``spot_density``: ``_marching`` (Crank-Nicolson /
ADI in height), ``_spectral`` (cosine series), ``_elliptic`` (sparse steady operator
with ``b_par > 0``), ``_transient`` (BDF2), ``_pde`` (the py-pde reference), and for
axisymmetric grids and hoppers ``_geometry`` (finite volumes with the metric and the
staircase) and ``_metric_march`` (their height marching).
"""
