// Run Python code in real MicroPython (the WebAssembly build of the npm package pinned in
// package.json) with Python packages copied into its in-memory filesystem.
//
//   node tools/mpy/run.mjs [--pkg DIR]... [--heap BYTES] SCRIPT.py   (SCRIPT "-" = stdin)
//
// Every `*.py` file of each DIR is written to /lib/<basename(DIR)>/ (on MicroPython's
// sys.path). The script's stdout is passed through byte for byte. Exit status: 0 when the
// script ran to the end, 1 when it raised (traceback on stderr; the package's own CLI
// runner exits 0 in that case, which is why the tests use this file), 2 on harness errors.
import { readFileSync, readdirSync } from "node:fs";
import { basename, dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const pkgDir = join(here, "node_modules", "@micropython", "micropython-webassembly-pyscript");

function usage(msg) {
  process.stderr.write(`run.mjs: ${msg}\n`);
  process.stderr.write("usage: node run.mjs [--pkg DIR]... [--heap BYTES] SCRIPT.py\n");
  process.exit(2);
}

const pkgs = [];
let heap = 16 * 1024 * 1024;
let script = null;
const argv = process.argv.slice(2);
for (let i = 0; i < argv.length; i++) {
  if (argv[i] === "--pkg" && i + 1 < argv.length) pkgs.push(argv[++i]);
  else if (argv[i] === "--heap" && i + 1 < argv.length) heap = parseInt(argv[++i], 10);
  else if (script === null) script = argv[i];
  else usage(`unexpected argument ${argv[i]}`);
}
if (script === null) usage("no script");

let mod;
try {
  mod = await import(join(pkgDir, "micropython.mjs"));
} catch (e) {
  usage(`cannot load the MicroPython package (run npm ci in tools/mpy): ${e.message}`);
}

const out = [];
const err = [];
const mp = await mod.loadMicroPython({
  heapsize: heap,
  linebuffer: false,
  stdout: (b) => out.push(b[0]),
  stderr: (b) => err.push(b[0]),
});

try { mp.FS.mkdir("/lib"); } catch (e) { /* exists */ }
for (const dir of pkgs) {
  const dest = "/lib/" + basename(dir.replace(/\/+$/, ""));
  mp.FS.mkdir(dest);
  for (const name of readdirSync(dir)) {
    if (name.endsWith(".py")) mp.FS.writeFile(`${dest}/${name}`, readFileSync(join(dir, name)));
  }
}

const code = readFileSync(script === "-" ? 0 : script, "utf8");
let status = 0;
try {
  mp.runPython(code);
} catch (e) {
  if (e && e.name === "PythonError") {
    err.push(...Buffer.from(`MicroPython raised ${e.type}: ${e.message}\n`));
    status = 1;
  } else {
    err.push(...Buffer.from(`run.mjs: ${e && e.stack ? e.stack : e}\n`));
    status = 2;
  }
}
process.stdout.write(Buffer.from(out));
process.stderr.write(Buffer.from(err));
process.exitCode = status;
