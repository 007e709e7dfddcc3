// Khronos' glTF validator (the npm package gltf-validator) run on many glTF/GLB files in one
// node process, for gnss_citygml/validate/gltf.py.
//
//   node gltf_validate.mjs VALIDATOR_PREFIX MAX_ISSUES FILE...
//
// VALIDATOR_PREFIX is the folder `npm install --prefix` installed gltf-validator into. For each
// FILE, in order, one line of JSON on stdout: {"file", "version", "numErrors", "numWarnings",
// "numInfos", "numHints", "messages": [{"code", "severity", "pointer", "message"}]} (severity
// 0 error, 1 warning, 2 information, 3 hint; at most MAX_ISSUES messages, errors first), or
// {"file", "failure"} when the file cannot be read or is neither glTF nor GLB. External
// resources (a .bin, an image) are read relative to the file; a URI with a scheme (http:...)
// is refused, so nothing is fetched from the network.
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";
import path from "node:path";
import { pathToFileURL } from "node:url";

const [prefix, maxIssues, ...files] = process.argv.slice(2);
const require = createRequire(pathToFileURL(path.join(path.resolve(prefix), "package.json")));
const validator = require("gltf-validator");

function resources(file) {
  const folder = path.dirname(path.resolve(file));
  return async (uri) => {
    if (/^[a-zA-Z][a-zA-Z0-9+.-]*:/.test(uri)) {
      throw new Error(`external resource with a scheme refused: ${uri}`);
    }
    return new Uint8Array(await readFile(path.resolve(folder, decodeURIComponent(uri))));
  };
}

for (const file of files) {
  let line;
  try {
    const data = new Uint8Array(await readFile(file));
    const report = await validator.validateBytes(data, {
      uri: path.basename(file),
      maxIssues: 0,
      writeTimestamp: false,
      externalResourceFunction: resources(file),
    });
    const issues = report.issues;
    const messages = [...issues.messages]
      .sort((a, b) => a.severity - b.severity)
      .slice(0, Number(maxIssues))
      .map(({ code, severity, pointer, message }) => ({ code, severity, pointer, message }));
    line = {
      file,
      version: report.validatorVersion,
      numErrors: issues.numErrors,
      numWarnings: issues.numWarnings,
      numInfos: issues.numInfos,
      numHints: issues.numHints,
      messages,
    };
  } catch (error) {
    line = { file, failure: String(error && error.message ? error.message : error) };
  }
  process.stdout.write(JSON.stringify(line) + "\n");
}
