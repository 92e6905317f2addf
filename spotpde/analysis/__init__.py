"""Analysis of results: ``comparison`` (the spot model's mean flow against the
Kinematic Model, rule by rule) and ``layers`` (diagnostics of layered-silo runs)."""
