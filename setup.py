"""Package list for setuptools: the three source folders map onto one import tree.

pyproject.toml holds all metadata; this file only walks the folders so that a new
sub-package is picked up without editing a list by hand.
"""

from setuptools import find_packages, setup

ROOTS = {"hwbridge": "hwbridge", "hwbridge.protocols": "protocols", "hwbridge.devices": "devices"}

packages: list[str] = []
for name, folder in ROOTS.items():
    packages.append(name)
    packages.extend(f"{name}.{sub}" for sub in find_packages(folder))

setup(packages=packages)
