#!/usr/bin/env python3
"""editor_tool.py --editor DIR COMMAND ... - run the OpenPLC Editor's own Python code (from a
checkout of github.com/thiagoralves/editor, the OpenPLC_Editor's `editor` submodule) without its
GUI, to check our files with the Editor's parser and generator. Development aid: nothing here
runs in CI (the Editor is not a build dependency); it needs a Python with lxml.

  palette MBFB_Blocks.xml          load the palette library with the Editor's loader
                                   (plcopen.structures, as when the Editor starts) and list
                                   the blocks and pins it sees
  st PLC_XML OUT_ST [PALETTE_XML]  load a project with the Editor's PLCControler, save it back
                                   with the Editor's serializer (--resave) and write the ST its
                                   PLCGenerator produces (what "Generate program for OpenPLC
                                   Runtime" writes, minus the debugger lines)

The Editor's modules import wx only for translations (util/TranslationCatalogs.py) and for
drawing (graphics/); both are replaced by inert stand-ins here, which the loader and the
generator never call.
"""
import argparse
import os
import sys
import types


def _stub_gui():
    wx = types.ModuleType("wx")
    wx.GetTranslation = lambda s: s
    sys.modules.setdefault("wx", wx)
    sys.modules["graphics.GraphicCommons"] = types.ModuleType("graphics.GraphicCommons")


def load_editor(editor, palette=None):
    """Import the Editor's plcopen.structures from checkout `editor`, with the palette library
    `palette` registered as plc_lib/README.md asks; returns that module."""
    editor = os.path.abspath(editor)
    if not os.path.isfile(os.path.join(editor, "PLCGenerator.py")):
        raise SystemExit(f"{editor}: not an OpenPLC Editor checkout (no PLCGenerator.py)")
    sys.path.insert(0, editor)
    _stub_gui()
    import plcopen.definitions as d
    if palette:  # the one line plc_lib/README.md asks users to add to StdTC6Libs
        d.StdTC6Libs.append(("Modbus instruments (mbfb)", os.path.abspath(palette)))
    import plcopen.structures as s
    return s


def cmd_palette(args):
    s = load_editor(args.editor, args.palette)
    cat = [c for c in s.StdBlckLst if c["name"] == "Modbus instruments (mbfb)"]
    if not cat or not cat[0]["list"]:
        raise SystemExit("the Editor's loader found no block in the palette library")
    for b in cat[0]["list"]:
        print(f"{b['name']} ({b['type']}): in {[i[:2] for i in b['inputs']]} out {[o[:2] for o in b['outputs']]}")


def generate_st(plc_xml, out_st, resave=False):
    """With the Editor loaded (load_editor): open plc_xml with its PLCControler, save it back
    with its serializer if resave, and write the ST its PLCGenerator produces to out_st."""
    import PLCControler
    c = PLCControler.PLCControler()
    err = c.OpenXMLFile(os.path.abspath(plc_xml))
    if err:
        raise SystemExit(f"the Editor cannot open {plc_xml}: {err}")
    if resave:
        c.SaveXMLFile(os.path.abspath(plc_xml))
    _, errors, warnings = c.GenerateProgram(os.path.abspath(out_st))
    for w in warnings:
        print("warning:", w)
    if errors:
        raise SystemExit(f"the Editor's generator failed: {errors}")
    print(f"wrote {out_st}")


def cmd_st(args):
    load_editor(args.editor, args.palette)
    generate_st(args.plc_xml, args.out_st, args.resave)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--editor", required=True, help="checkout of thiagoralves/editor")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("palette")
    p.add_argument("palette")
    p.set_defaults(fn=cmd_palette)
    p = sub.add_parser("st")
    p.add_argument("plc_xml")
    p.add_argument("out_st")
    p.add_argument("palette", nargs="?")
    p.add_argument("--resave", action="store_true", help="rewrite PLC_XML as the Editor saves it")
    p.set_defaults(fn=cmd_st)
    args = ap.parse_args()
    args.fn(args)


if __name__ == "__main__":
    main()
