"""Example plant files (and, later, controller files) shipped with servofmu as package data.

The files live in fmu_models/ at the top of the repository; the package maps this folder to
``servofmu.fmu_models`` so that ``importlib.resources`` finds them in any installation.
"""
