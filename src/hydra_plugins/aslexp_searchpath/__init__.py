"""Hydra search-path plugin: makes the project's ``sweeps/`` folder a config group.

With it, ``aslexp recognize -m +sweeps=classifier_mlp`` composes ``sweeps/classifier_mlp.yaml``
from the project root, whichever directory the command runs from.
"""

from pathlib import Path

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin

_PROJECT_ROOT = Path(__file__).resolve().parents[3]


class AslexpSearchPathPlugin(SearchPathPlugin):
    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        if (_PROJECT_ROOT / "sweeps").is_dir():
            search_path.append(provider="aslexp", path=f"file://{_PROJECT_ROOT}")
