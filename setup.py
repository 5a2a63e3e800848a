"""The package list, found rather than kept by hand (setup.cfg holds everything else): every
folder of clss, weights_tools and bench with an __init__.py, so that a new method's room
(clss/methods/<name>/) is installed with no line here, plus clss.kernels, the top-level
kernels/ (a porter finds it first) installed as the package data folder clss/kernels
(setup.cfg's package_dir), which a search cannot find since it holds no Python."""
from setuptools import find_packages, setup

setup(packages=find_packages(include=["clss", "clss.*", "weights_tools", "weights_tools.*",
                                      "bench", "bench.*"]) + ["clss.kernels"])
