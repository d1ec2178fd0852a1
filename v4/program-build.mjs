// program-build.mjs: a program's core/generated/ folder as the OpenPLC Editor v4 writes it for
// Runtime v4 to compile (scripts/compile.sh, scripts/Makefile.strucpp), from ST, with STruC++.
//
//   node program-build.mjs --strucpp STRUCPP_DIR [-L LIBDIR]... -o OUT_DIR PROGRAM.st [MORE.st...]
//
// OUT_DIR gets generated.cpp / generated.hpp (the program), generated_debug.cpp and
// debug-map.json (the debugger's tables: runtime_v4_entry.cpp links against them, and the
// map gives each variable's (array, element) address for the runtime's DEBUG commands),
// defines.h (PROGRAM_MD5, the MD5 of the sources) and strucpp_runtime/include/ (STruC++'s
// runtime headers, which the Editor ships with every upload). STruC++'s command line writes
// only the first two, hence this script; it calls the same compile() the command line does,
// with STruC++'s bundled libraries (the IEC standard FBs) and each -L folder's .stlib files.
import { cpSync, mkdirSync, readFileSync, writeFileSync } from "node:fs";
import { createHash } from "node:crypto";
import { basename, join, resolve } from "node:path";
import { pathToFileURL } from "node:url";

function usage(msg) {
  if (msg) console.error(`program-build.mjs: ${msg}`);
  console.error("usage: node program-build.mjs --strucpp STRUCPP_DIR [-L LIBDIR]... -o OUT_DIR PROGRAM.st [MORE.st...]");
  process.exit(2);
}

const args = process.argv.slice(2);
let strucpp = "";
let out = "";
const libDirs = [];
const inputs = [];
for (let i = 0; i < args.length; i++) {
  const a = args[i];
  if (a === "--strucpp") strucpp = args[++i] ?? "";
  else if (a === "-o") out = args[++i] ?? "";
  else if (a === "-L") libDirs.push(args[++i] ?? "");
  else if (a.startsWith("-")) usage(`unknown option ${a}`);
  else inputs.push(a);
}
if (!strucpp || !out || inputs.length === 0) usage("");

const dist = resolve(strucpp, "dist");
const { compile } = await import(pathToFileURL(join(dist, "index.js")).href);
const { discoverStlibs } = await import(pathToFileURL(join(dist, "node", "library-loader.js")).href);

const sources = inputs.map((p) => ({ source: readFileSync(p, "utf-8"), fileName: basename(p) }));
const md5 = createHash("md5");
for (const s of sources) md5.update(s.source);
const programMd5 = md5.digest("hex");

const libraries = [resolve(strucpp, "libs"), ...libDirs].flatMap((d) => discoverStlibs(resolve(d)));
const result = compile(sources[0].source, {
  fileName: sources[0].fileName,
  additionalSources: sources.slice(1),
  headerFileName: "generated.hpp",
  libraries,
  md5: programMd5,
});
if (!result.success) {
  for (const e of result.errors) {
    console.error(`${e.file ?? sources[0].fileName}:${e.line ?? 0}:${e.column ?? 0}: ${e.message}`);
  }
  process.exit(1);
}
if (result.debugTableCpp === undefined || result.debugMap === undefined) {
  console.error("program-build.mjs: STruC++ produced no debug table (the runtime's entry shim needs it)");
  process.exit(1);
}
mkdirSync(out, { recursive: true });
writeFileSync(join(out, "generated.cpp"), result.cppCode);
writeFileSync(join(out, "generated.hpp"), result.headerCode);
writeFileSync(join(out, "generated_debug.cpp"), result.debugTableCpp);
writeFileSync(join(out, "debug-map.json"), JSON.stringify(result.debugMap, null, 2));
writeFileSync(join(out, "defines.h"), `#define PROGRAM_MD5 "${programMd5}"\n`);
cpSync(resolve(strucpp, "src", "runtime", "include"), join(out, "strucpp_runtime", "include"),
       { recursive: true });
console.log(`program-build.mjs: ${out} (md5 ${programMd5})`);
