"""nao-trainer: personalised robot-assisted cognitive training (NAO + Muse EEG + Q-learning)."""
import re
from pathlib import Path

from setuptools import find_namespace_packages, setup

here = Path(__file__).parent
version = re.search(r'__version__ = "([^"]+)"', (here / "nao_trainer" / "__init__.py").read_text()).group(1)

setup(
    name="nao-trainer",
    version=version,
    description="Personalised robot-assisted cognitive training with a NAO robot and a Muse EEG headband",
    long_description=(here / "README.md").read_text() if (here / "README.md").exists() else "",
    long_description_content_type="text/markdown",
    # namespace packages too: console/static (the page, no __init__.py) is then a package of its own, not data
    # setuptools warns about on every install
    packages=find_namespace_packages(include=["nao_trainer", "nao_trainer.*"], exclude=["*.__pycache__"]),
    # qi 3.1.5 (the NAOqi SDK) on the package index: wheels for CPython 3.8-3.12, Linux x86_64 only (pip download
    # per version, 2026-12: none for 3.13, macOS, Windows, Linux aarch64); the project itself needs 3.10+.
    python_requires=">=3.10,<3.13",
    install_requires=[
        "qi==3.1.5",
        "numpy>=1.24",
        "scikit-learn>=1.5",
        "scipy>=1.10",
        "pyyaml>=6",
        "pylsl>=1.16",
        "transitions>=0.9",
    ],
    extras_require={
        "plots": ["matplotlib>=3.7"],
        "gym": ["gymnasium>=1.0"],
        "console": ["starlette>=0.37", "uvicorn>=0.29"],
        # the compiled learner (core.qkernel); without it training runs the numpy learner (same results)
        "fast": ["numba>=0.60"],
        # fan-out of training, sweeps and evaluations (learn.parallel); dask://HOST:PORT backends
        "cluster": ["joblib>=1.3", "dask[distributed]>=2024.1"],
        # session.xdf: LabRecorder's engine (a release candidate, binary wheels) and the reader
        "xdf": ["labrecorder>=1.0.0rc0", "pyxdf>=1.16"],
        # EEG device 'brainflow': the Muse 2 / Muse S natively and BrainFlow's synthetic board (eeg/devices/brainflow.py)
        "brainflow": ["brainflow>=5.10"],
        # controlled studies: the mixed model (study analyse), BIDS export (study export --bids)
        # + the sealed allocation of the study registry (study.seal: Fernet)
        "study": ["statsmodels>=0.14", "pandas>=2", "mne>=1.6", "mne-bids>=0.15", "pybv>=0.7", "cryptography>=41"],
        # the study registry on a PostgreSQL server (study.pg; several sites, blinding by the database's roles)
        "study-pg": ["psycopg[binary]>=3.1"],
        # QUEST+ baseline beside the Bayes ceiling (experiments.adaptive)
        "psychophysics": ["questplus>=2023.1"],
        # the documentation site (make docs): MkDocs, the Material theme, the API pages from the docstrings
        "docs": ["mkdocs>=1.6", "mkdocs-material>=9.5", "mkdocstrings[python]>=0.26"],
        "test": ["mkdocs>=1.6", "mkdocs-material>=9.5", "mkdocstrings[python]>=0.26", "pytest>=7", "pytest-xdist>=3.6", "playwright>=1.40", "pyxdf>=1.16", "statsmodels>=0.14", "pandas>=2",
                 "mne>=1.6", "mne-bids>=0.15", "pybv>=0.7", "questplus>=2023.1", "brainflow>=5.10", "cryptography>=41", "psycopg[binary]>=3.1"],
        "all": ["matplotlib>=3.7", "gymnasium>=1.0", "starlette>=0.37", "uvicorn>=0.29", "numba>=0.60", "joblib>=1.3",
                "dask[distributed]>=2024.1", "labrecorder>=1.0.0rc0", "pyxdf>=1.16", "statsmodels>=0.14", "pandas>=2",
                "mne>=1.6", "mne-bids>=0.15", "pybv>=0.7", "questplus>=2023.1", "brainflow>=5.10", "cryptography>=41", "psycopg[binary]>=3.1"],
    },
    # The console's page and the vendored uPlot (MIT; version and licence in console/static/).
    package_data={"nao_trainer.console.static": ["*"]},
    entry_points={"console_scripts": ["nao-trainer=nao_trainer.cli:entry_point"]},
    include_package_data=True,
    classifiers=[
        "Programming Language :: Python :: 3.10",
        "Programming Language :: Python :: 3.11",
        "Programming Language :: Python :: 3.12",
        "Operating System :: POSIX :: Linux",
    ],
)
