"""The package's runtime basement: worker processes and their reaping, parallel backends
(local processes or Ray, one code path), and locks on output folders. Nothing here knows
about arms, observers or controllers."""
