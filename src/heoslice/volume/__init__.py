"""Volumes as models (issue 45): label maps and intensity volumes (CT) read into one typed
:class:`Volume` (:mod:`~heoslice.volume.readers`), described (:mod:`~heoslice.volume.info`), placed in the
printer's frame (:mod:`~heoslice.volume.placement`) and resampled layer by layer into per-material masks
(:mod:`~heoslice.volume.fields`, :mod:`~heoslice.volume.layers`), meeting the mesh route at the layer.
"""

from heoslice.volume.model import Label, Volume
from heoslice.volume.readers import VOLUME_SUFFIXES, is_volume_path, load_volume

__all__ = ["VOLUME_SUFFIXES", "Label", "Volume", "is_volume_path", "load_volume"]
