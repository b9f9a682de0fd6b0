"""Packages are listed here because setup.cfg cannot compute them.

The four top-level folders are installed as subpackages of one `sosmatch` namespace (see package_dir in
setup.cfg); every folder below them with an __init__.py is found automatically.
"""

from setuptools import find_packages, setup

TOP_LEVEL = ("plugin", "database", "workflows", "tools")
packages = [
    "sosmatch." + name
    for name in find_packages(include=[f"{top}*" for top in TOP_LEVEL])
    if name.split(".")[0] in TOP_LEVEL
]
setup(packages=packages)
