"""PNG previews of a stack for people who would rather look: one layer, a contact sheet, a vertical section.

Every layer shown is read through :mod:`heoslice.stack`: the manifest is checked, each
file must stay inside the stack and match its sha256 and layout before it is decoded.
"""

from heoslice.preview.layer import (annotated_layer_image, channel_colors, channels_rgb, fit, layer_display,
                                    layer_image, layer_rgb)
from heoslice.preview.section import annotated_section_image, parse_section, section_image
from heoslice.preview.sheet import contact_sheet, parse_layers, sheet_size

__all__ = ["annotated_layer_image", "annotated_section_image", "channel_colors", "channels_rgb", "contact_sheet", "fit", "layer_display", "layer_image", "layer_rgb",
           "parse_layers", "parse_section", "section_image", "sheet_size"]
