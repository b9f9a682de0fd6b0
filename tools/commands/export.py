"""`sosmatch export --geojson SESSION_OR_MAP --out FILE`: landmarks for GIS and point-cloud tools."""

from __future__ import annotations

import argparse
from pathlib import Path

from ...database.json_text import json_text
from ._common import output_file

NAME = "export"
HELP = "export landmarks of a session or .sosmap as GeoJSON (WGS84, for QGIS), PLY or CSV"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", type=Path, help="mapped session directory or landmarks .sosmap file")
    fmt = parser.add_mutually_exclusive_group(required=True)
    fmt.add_argument("--geojson", action="store_const", const="geojson", dest="format",
                     help="GeoJSON FeatureCollection in WGS84 (needs a georeferenced map or --epsg)")
    fmt.add_argument("--ply", action="store_const", const="ply", dest="format", help="binary PLY (double xyz)")
    fmt.add_argument("--csv", action="store_const", const="csv", dest="format", help="CSV (+ lon/lat if known)")
    parser.add_argument("--out", type=output_file, required=True, help="file to write")
    parser.add_argument("--epsg", type=int, help="EPSG code of the world frame of a map saved without one (another "
                        "code than the one a map records is refused: it would relabel, not reproject)")
    parser.add_argument("--circles", action="store_true", help="GeoJSON polygons of each landmark's size")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a file this command exported before from another map or with other options")


def run(args: argparse.Namespace) -> int:
    from ...workflows.export import run as export

    kwargs = {"geojson": None, "ply": None, "csv_out": None}
    kwargs[{"geojson": "geojson", "ply": "ply", "csv": "csv_out"}[args.format]] = args.out
    result = export(args.source, epsg=args.epsg, geometry="circle" if args.circles else "point",
                    overwrite=args.overwrite, **kwargs)
    print(json_text(result))
    return 0
