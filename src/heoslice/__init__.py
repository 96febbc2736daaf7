"""heoslice: graded multi-material slicing for jetting bio-printers.

The pipeline, one module per stage:
loading -> distribution/materials (colour) -> slicing -> contours -> regions
-> rasterising -> stack (on disk) -> protocol/printer (to the controller).
"""

__version__ = "0.1.0"
