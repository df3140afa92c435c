"""Files the programs load: the ROV mesh, the seabed texture and its metadata,
sample images (images/).  Installed as package data of `rovlink.assets`."""

from pathlib import Path

ASSETS_DIR = Path(__file__).resolve().parent
