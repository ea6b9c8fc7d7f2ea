// Validate GLB/glTF files with the Khronos glTF validator; prints one JSON summary per file.
// Usage: node validate.js FILE.glb [...]; exit code 1 if any file has errors.
"use strict";
const fs = require("fs");
const validator = require("gltf-validator");

async function main(files) {
  let failed = 0;
  for (const file of files) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
      maxIssues: 100,
    });
    const i = report.issues;
    const summary = {
      file,
      errors: i.numErrors,
      warnings: i.numWarnings,
      infos: i.numInfos,
      messages: i.messages.filter((m) => m.severity === 0).slice(0, 20),
    };
    console.log(JSON.stringify(summary));
    if (i.numErrors > 0) failed += 1;
  }
  process.exit(failed ? 1 : 0);
}

main(process.argv.slice(2)).catch((e) => {
  console.error(e);
  process.exit(2);
});
