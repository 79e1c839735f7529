// The Khronos glTF-Validator on each file named on the command line: one
// JSON line per file, {"file", "errors", "warnings", "infos", "hints",
// "messages": [{code, severity, pointer, message}]} (severity 0 error, 1 warning).
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

async function main(files) {
  for (const file of files) {
    const bytes = new Uint8Array(fs.readFileSync(file));
    const report = await validator.validateBytes(bytes, {
      uri: path.basename(file),
      maxIssues: 100,
      externalResourceFunction: () => Promise.reject(new Error("no external resources")),
    });
    const issues = report.issues;
    console.log(JSON.stringify({
      file,
      errors: issues.numErrors,
      warnings: issues.numWarnings,
      infos: issues.numInfos,
      hints: issues.numHints,
      messages: issues.messages.map((m) => ({ code: m.code, severity: m.severity, pointer: m.pointer, message: m.message })),
    }));
  }
}

main(process.argv.slice(2)).catch((err) => {
  console.error(`validate.js: ${err.message || err}`);
  process.exit(1);
});
