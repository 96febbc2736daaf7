"""Reading meshes: one reader per format, each giving a :class:`RawMesh`; welding, topology, volume; the loaded Mesh.

A 3MF (objects, names, materials: :func:`read_3mf`) loads as an assembly, each build item a part;
:func:`load_assembly` makes one mesh of several files, each face labelled with its part.
"""

from heoslice.mesh.assembly import Part, assemble, load_assembly, uniform_color
from heoslice.mesh.checks import VolumeCheck, volume_check
from heoslice.mesh.load import MAX_COORDINATE, SUPPORTED_SUFFIXES, Mesh, column_bounds, file_sha256, load_mesh, \
    mesh_info, scaled, without_materials
from heoslice.mesh.ply import check_ply_header, parse_ply_header, read_ply
from heoslice.mesh.raw import MATERIAL_PROPERTY, RawMesh
from heoslice.mesh.threemf import Material, ModelObject, ThreeMF, read_3mf
from heoslice.mesh.topology import EdgeGroups, edge_groups, edge_use_counts, shell_labels
from heoslice.mesh.volume import ranked_part_volumes_mm3, signed_volume_mm3, solid_volume_mm3, winding_number

__all__ = [
    "MATERIAL_PROPERTY", "MAX_COORDINATE", "SUPPORTED_SUFFIXES", "EdgeGroups", "Material", "Mesh", "ModelObject",
    "RawMesh", "ThreeMF", "check_ply_header", "read_3mf",
    "column_bounds", "edge_groups", "edge_use_counts", "file_sha256", "load_mesh", "mesh_info", "parse_ply_header",
    "read_ply", "scaled", "shell_labels", "signed_volume_mm3", "solid_volume_mm3", "winding_number",
    "without_materials", "VolumeCheck", "volume_check", "Part", "assemble", "load_assembly", "uniform_color",
    "ranked_part_volumes_mm3",
]
