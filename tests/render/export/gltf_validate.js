// Runs the Khronos glTF validator (npm gltf-validator) on one .glb and prints its report as JSON.
// usage: node gltf_validate.js NODE_MODULES_DIR FILE.glb
'use strict';
const fs = require('fs');
const path = require('path');
const validator = require(path.join(process.argv[2], 'gltf-validator'));
const bytes = new Uint8Array(fs.readFileSync(process.argv[3]));
validator.validateBytes(bytes, {maxIssues: 1000, uri: path.basename(process.argv[3])})
    .then((report) => console.log(JSON.stringify(report)))
    .catch((error) => {
      console.error('gltf-validator failed: ' + error);
      process.exit(1);
    });
