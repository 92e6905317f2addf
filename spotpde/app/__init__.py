"""The application layer: case files in, netCDF and figures out.

``cases`` (TOML schema and validation) -> ``pipeline`` (runs the stages) -> ``io``
(xarray Dataset, netCDF) -> ``plotting``; ``sweep`` runs parameter sweeps on Dask. The
``spotpde`` command is :mod:`spotpde.cli`, a layer above (it also uses the data-in
stages, which use this one).
"""
