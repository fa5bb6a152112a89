"""Triangle meshes (STL, PLY, OBJ, OFF, GLB through trimesh): one reader, checked, for the
simulator's mesh scenes and ``scanqa compare``'s reference.

A mesh is read with ``trimesh.load(..., force="mesh")`` and then checked before anything
uses it: at least one triangle, vertices of three finite coordinates, faces of three
vertex indices that exist. A damaged file fails here with one :class:`InputError` naming
it; trimesh accepts some (faces pointing past the vertex list, two-coordinate OBJ
vertices) that would otherwise fail later, deep in a ray caster.
"""

from __future__ import annotations

import os
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np

from scanqa.errors import InputError

#: What trimesh raises on a damaged or unsupported file (measured on truncated, bit-flipped
#: and garbled STL, PLY and OBJ files); anything else is a bug and is not hidden.
MESH_ERRORS = (ValueError, KeyError, IndexError, TypeError, EOFError, OSError, struct.error,
               zlib.error)
#: What trimesh's glTF/GLB reader raises on a file whose JSON holds values of the wrong kind
#: (``{"asset": 5}``, an accessor without its buffer view): errors that would be bugs
#: anywhere else, so they count as the file's fault only when raised inside trimesh.
DAMAGE_IN_TRIMESH = (AttributeError, NameError, ArithmeticError, RecursionError,
                     AssertionError)


def raised_in(err: BaseException, package: str) -> bool:
    """Whether a frame of ``err``'s traceback lies in ``package``'s own source."""
    import importlib.util

    spec = importlib.util.find_spec(package)
    roots = [str(Path(r).resolve()) for r in (spec.submodule_search_locations or [])] \
        if spec is not None else []
    tb = err.__traceback__
    while tb is not None:
        name = str(Path(tb.tb_frame.f_code.co_filename).resolve())
        if any(name.startswith(root + os.sep) for root in roots):
            return True
        tb = tb.tb_next
    return False


#: Suffixes always read as meshes (a .ply is a mesh when it declares faces).
MESH_SUFFIXES = (".stl", ".obj", ".off", ".glb", ".gltf")


def is_mesh_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a mesh: a mesh suffix, or a PLY whose header declares at least
    one face (``element face N``, N > 0); other files (clouds) are False."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in MESH_SUFFIXES:
        return True
    if suffix != ".ply" or not p.is_file():
        return False
    with open(p, "rb") as fh:
        head = fh.read(65536)
    for line in head.split(b"end_header", 1)[0].splitlines():
        words = line.split()
        if len(words) == 3 and words[:2] == [b"element", b"face"]:
            return words[2].isdigit() and int(words[2]) > 0
    return False


def read_mesh(path: str | os.PathLike):
    """Read and check a triangle mesh (module notes).

    Parameters
    ----------
    path : str or PathLike
        The mesh file [mm coordinates, as the scan's].

    Returns
    -------
    trimesh.Trimesh
        The mesh, (n, 3) finite vertices and (m, 3) faces indexing them.

    Raises
    ------
    InputError
        The file is missing, unreadable, holds no triangles or holds malformed ones.
    """
    import trimesh

    p = Path(path)
    if not p.is_file():
        raise InputError(f"mesh file {p} does not exist")
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")  # a damaged file's casts: the checks below say it
            mesh = trimesh.load(p, force="mesh")
    except (*MESH_ERRORS, *DAMAGE_IN_TRIMESH) as err:
        if not isinstance(err, MESH_ERRORS) and not raised_in(err, "trimesh"):
            raise  # not the file: a bug, not hidden
        raise InputError(f"cannot load mesh {p}: {type(err).__name__}: {err} (need a valid "
                         "STL, PLY, OBJ, OFF or GLB file)") from None
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))))
    if not isinstance(mesh, trimesh.Trimesh) or faces.size == 0:
        raise InputError(f"mesh {p} holds no triangles (a point cloud? give it as a cloud; "
                         "else need a valid STL, PLY, OBJ or OFF file)")
    vertices = np.asarray(mesh.vertices)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(f"mesh {p}: vertices have {vertices.shape[-1]} coordinates, need "
                         "x, y, z (damaged file?)")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"mesh {p}: faces are not triangles of 3 vertex indices (damaged "
                         "file?)")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"mesh {p}: a face refers to vertex {int(faces.max())} (or "
                         f"{int(faces.min())}) but there are {len(vertices)} (damaged file?)")
    if not np.isfinite(vertices).all():
        raise InputError(f"mesh {p} has vertices with NaN or infinite coordinates")
    return mesh
