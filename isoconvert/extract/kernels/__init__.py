"""numba kernels: plain arrays and scalars in, arrays out; no validation here.

This package imports numba, so import it only when extracting: ``--help``,
``info`` and ``check`` must not pay numba's start-up price.
"""
