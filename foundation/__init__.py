"""The ground floor: the small modules every layer uses (the one input error, atomic writes,
TOML reading). It imports no other package of iblbench."""
