"""The stack on disk: layer TIFFs plus ``manifest.json`` (format: ``docs/stack-format.md``).

``manifest`` holds the schema (built and checked there), ``tiff`` the layer encoding
and its defensive decoding, ``write`` the safe writing, ``read`` the bounded reading
``verify`` the whole-stack check that ``print`` and ``preview`` rely on, and ``printable`` the one rule of
which stacks can print.
"""

from heoslice.stack.manifest import (
    FORMAT_NAME,
    FORMAT_VERSION,
    IMAGE_MODES,
    LAYER_PATTERN,
    MANIFEST,
    MAX_IMAGE_PIXELS,
    MAX_LAYERS,
    MAX_MANIFEST_BYTES,
    MAX_MANIFEST_CONTAINERS,
    ChannelRecord,
    ImageRecord,
    LayerRecord,
    build_manifest,
    check_image_size,
    droplet_summary,
    expected_layer_count,
    grading_summary,
    layer_file_name,
    layer_height_problems,
    manifest_problem,
    mask_channels,
    max_layer_count,
    parse_manifest,
    source_scale,
    stack_volume_mm3,
    widest_masks,
)
from heoslice.stack.read import (
    check_input_path,
    decode_mask,
    incomplete_stack,
    layer_strips,
    read_layer_channels,
    read_layer_mask,
    read_layer_pixels,
    read_manifest,
    resolve_inside,
)
from heoslice.stack.printable import PRINT_RULES, PrintRule, check_printable, print_refusal, refusal_line
from heoslice.stack.tiff import COMPRESSIONS, DEFAULT_COMPRESSION, encode_bilevel_tiff, encode_tiff
from heoslice.stack.verify import StackReport, load_verified, verify_stack
from heoslice.stack.write import check_stack_output, is_stack_folder, prepare_directory, write_file, write_manifest

__all__ = [
    "COMPRESSIONS", "DEFAULT_COMPRESSION", "FORMAT_NAME", "FORMAT_VERSION", "IMAGE_MODES", "LAYER_PATTERN",
    "MANIFEST", "MAX_IMAGE_PIXELS", "MAX_LAYERS", "MAX_MANIFEST_BYTES", "MAX_MANIFEST_CONTAINERS", "ChannelRecord",
    "ImageRecord", "LayerRecord", "StackReport", "build_manifest", "check_stack_output", "is_stack_folder", "check_image_size", "check_input_path",
    "decode_mask", "droplet_summary", "incomplete_stack", "encode_bilevel_tiff", "encode_tiff", "expected_layer_count", "grading_summary",
    "layer_file_name", "layer_height_problems", "layer_strips", "load_verified", "manifest_problem", "mask_channels",
    "max_layer_count", "parse_manifest",
    "prepare_directory", "read_layer_channels", "read_layer_mask", "read_layer_pixels", "read_manifest",
    "resolve_inside", "stack_volume_mm3", "verify_stack", "widest_masks", "write_file", "write_manifest",
    "PRINT_RULES", "PrintRule", "check_printable", "print_refusal", "refusal_line", "source_scale",
]
