"""The package layout, which pyproject.toml cannot state: the source folders of the
design card (schemas/, kernels/, service/, clients/) install as one namespace,
`flocklab.schemas`, `flocklab.kernels`, ... so that no generic top-level name
(`kernels` is a PyPI distribution too) is put into site-packages."""

from setuptools import find_namespace_packages, setup

PARTS = ("schemas", "kernels", "service", "clients")

setup(
    # Namespace discovery: folders of data (service/app/static) are packages too.
    packages=["flocklab"] + [f"flocklab.{p}" for p in find_namespace_packages(
        include=[f"{part}{tail}" for part in PARTS for tail in ("", ".*")],
        exclude=["*.__pycache__"])],
    package_dir={"flocklab": "flocklab", **{f"flocklab.{part}": part for part in PARTS}},
)
