"""Materials of a model: distribution functions, reference features and distances, colouring, the materials table.

Modules, in the order a material distribution is built (paper section II.B, III.A):
``expressions`` (formulas in r, parsed, never eval'ed), ``functions`` (eq. 2-5 as one
table of kinds), ``triangles`` and ``surface`` (exact point-triangle and nearest-surface
distance), ``references`` (plane, point, axis, surface as one table of kinds, and r),
``materials`` (the TOML materials table, eq. 1's blend and the default roles of M1 and
M2), ``coloring`` (a mesh coloured by a function and written as PLY).
"""

from heoslice.material.coloring import (
                                        MAX_SUBDIVIDED_TRIANGLES,
                                        ColoredMesh,
                                        ColorSpec,
                                        color_mesh,
                                        default_output,
                                        material_comment,
                                        ply_bytes,
                                        subdivide,
                                        write_ply,
)
from heoslice.material.expressions import (
                                        EXPRESSION_CONSTANTS,
                                        EXPRESSION_FUNCTIONS,
                                        compile_expression,
                                        evaluate_expression,
)
from heoslice.material.functions import (
                                        FUNCTION_KINDS,
                                        FUNCTIONS,
                                        DistributionFunction,
                                        FunctionKind,
                                        evaluate,
                                        make_function,
)
from heoslice.material.materials import (
                                        DEFAULT_MATERIALS,
                                        MAX_CHANNEL,
                                        Material,
                                        MaterialRoles,
                                        MaterialsFile,
                                        PartSetting,
                                        blend,
                                        check_one_per_channel,
                                        is_channel,
                                        material_roles,
                                        nearest_materials,
                                        parse_color,
                                        read_materials_file,
                                        resolve_material,
                                        shared_channel,
                                        table_material,
                                        to_rgb8,
                                        with_table_channels,
)
from heoslice.material.references import (
                                        REFERENCE_KINDS,
                                        REFERENCES,
                                        Reference,
                                        ReferenceKind,
                                        make_reference,
                                        material_fraction,
                                        normalise,
                                        reference_distance,
                                        reference_kinds_taking,
)
from heoslice.material.surface import (
                                        SurfaceIndex,
                                        build_surface_index,
                                        surface_distance,
)
from heoslice.material.triangles import (
                                        closest_points_on_triangles,
                                        point_triangle_distance,
)

__all__ = [
    "MAX_SUBDIVIDED_TRIANGLES", "ColoredMesh", "ColorSpec", "color_mesh", "default_output", "material_comment",
    "ply_bytes", "subdivide", "write_ply",
    "EXPRESSION_CONSTANTS", "EXPRESSION_FUNCTIONS", "compile_expression", "evaluate_expression",
    "FUNCTION_KINDS", "FUNCTIONS", "DistributionFunction", "FunctionKind", "evaluate", "make_function",
    "DEFAULT_MATERIALS", "MAX_CHANNEL", "Material", "MaterialRoles", "blend",
    "material_roles", "nearest_materials", "parse_color", "resolve_material", "shared_channel", "to_rgb8",
    "with_table_channels",
    "PartSetting", "table_material", "MaterialsFile", "read_materials_file",
    "check_one_per_channel",
    "is_channel",
    "REFERENCE_KINDS", "REFERENCES", "Reference", "ReferenceKind", "make_reference", "material_fraction",
    "normalise", "reference_distance", "reference_kinds_taking",
    "SurfaceIndex", "build_surface_index", "surface_distance",
    "closest_points_on_triangles", "point_triangle_distance",
]
