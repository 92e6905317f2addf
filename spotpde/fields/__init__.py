"""Stage 2: influence kernels and the particles' drift and diffusivity.

* :mod:`~spotpde.fields.kernels`: the influence kernel ``w`` (uniform, Gaussian,
  exponential; ``V1``, ``V2``, velocity correlations);
* :mod:`~spotpde.fields.convolution`: linear (zero-padded) FFT convolution;
* :mod:`~spotpde.fields.coefficients`: ``u_p`` and ``D_p`` from ``rho_s``;
* :mod:`~spotpde.fields.void`: the void model's fields and closed forms.
"""
