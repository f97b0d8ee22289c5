"""Package list for setuptools: the three source folders map onto one import tree.

pyproject.toml holds all metadata; this file only walks the folders so that a new
sub-package is picked up without editing a list by hand.
"""

from setuptools import find_namespace_packages, setup

ROOTS = {"hwbridge": "hwbridge", "hwbridge.protocols": "protocols", "hwbridge.devices": "devices"}

# Data folders (emulator/boards, msg/..., vectors) count as namespace packages: listing them
# keeps setuptools from warning, on every install, that they "would be ignored".
packages: list[str] = []
for name, folder in ROOTS.items():
    packages.append(name)
    packages.extend(
        f"{name}.{sub}"
        for sub in find_namespace_packages(folder, exclude=["*__pycache__*", "build*"])
    )

setup(packages=packages)
