"""The application layer: case files in, netCDF and figures out.

``cases`` (TOML schema and validation) -> ``pipeline`` (runs the stages) -> ``io``
(xarray Dataset, netCDF) -> ``plotting``; ``cli`` is the ``spotpde`` command and
``sweep`` runs parameter sweeps on Dask.
"""
