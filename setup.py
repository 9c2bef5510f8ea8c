"""The packages setuptools builds, with the udev rules mapped in.

Everything else is in pyproject.toml; this file exists for one thing pyproject.toml cannot say
alongside `packages.find`: the rules live in udev/ at the top of the repository (where the
design card has them) and are shipped as the package `micam.data.udev`, where
`micam install udev` reads them from an installed wheel (micam/data/__init__.py).
"""

from setuptools import find_namespace_packages, setup

PACKAGES = ["kernel*", "daq*", "sim*", "acquisition*", "calibration*", "imaging*", "micam*"]

setup(packages=[*find_namespace_packages(include=PACKAGES), "micam.data.udev"],
      package_dir={"micam.data.udev": "udev"})
