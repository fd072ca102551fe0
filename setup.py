"""Build hook for what pyproject.toml cannot say: the wheel carries the top-level conf/ (the Hydra configs) as the
package data drs_torchrl/conf, where conf_dir() finds it in an installed package. Metadata: pyproject.toml."""

from setuptools import find_namespace_packages, find_packages, setup

conf = ["drs_torchrl.conf", *(f"drs_torchrl.conf.{p}" for p in find_namespace_packages("conf"))]  # algo, env, ...
setup(
    packages=[*find_packages("src", include=["drs_torchrl", "drs_torchrl.*"]), *conf],
    package_dir={"": "src", "drs_torchrl.conf": "conf"},
    package_data={p: ["*.yaml"] for p in conf},
)
