"""Pure numpy/scipy/numba implementation of the method; never imports bpy.

Each module holds one concept of Sun et al. 2022 ("Efficient Texture Parameterization Driven by
Perceptual-Loss-on-Screen", CGF 41(7)); equation numbers in docstrings are the paper's.
"""
