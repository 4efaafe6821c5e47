"""The surface over time for ParaView: XDMF (one .xdmf + .h5) with the membrane's fields."""

import capsim
from capsim.face.export import export_to_dir

from _common import OUT, ROOT, TINY


def main():
    case = capsim.load_case(ROOT / "configs" / "sphere.yaml", mesh__level=0 if TINY else 2,
                            time__t_end=0.2 if TINY else 5.0, output__path=str(OUT / "export.h5"),
                            output__snapshot_every=0.1 if TINY else 0.5)
    result = capsim.run(case, overwrite=True)
    files = export_to_dir(result.path, OUT / "export_xdmf", "xdmf", overwrite=True)
    print(f"open {files[0]} in ParaView (XDMF reader); {len(files)} files")


if __name__ == "__main__":
    main()
