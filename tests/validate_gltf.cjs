// Runs the Khronos glTF validator (npm gltf-validator, installed in web/ by
// `make install`) on each file named on the command line and prints one JSON
// report per file: {file, errors, warnings, messages}.
const fs = require("fs");
const path = require("path");
const validator = require(path.join(__dirname, "..", "web", "node_modules", "gltf-validator"));

(async () => {
  const reports = [];
  for (const file of process.argv.slice(2)) {
    const result = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
      uri: path.basename(file),
      maxIssues: 200,
      externalResourceFunction: (uri) =>
        Promise.resolve(new Uint8Array(fs.readFileSync(path.join(path.dirname(file), decodeURIComponent(uri))))),
    });
    reports.push({ file, errors: result.issues.numErrors, warnings: result.issues.numWarnings,
                   messages: result.issues.messages });
  }
  console.log(JSON.stringify(reports));
})().catch((e) => { console.error(e); process.exit(2); });
