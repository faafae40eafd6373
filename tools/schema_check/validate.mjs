// Usage: node validate.mjs SCHEMA.json DATA.json [EXTRA_SCHEMA.json ...]
// Validates DATA against SCHEMA (draft-07, with referenced schemas given as
// extras). Prints "valid" or one line per error; exit 0 when valid, 1 if not,
// 2 on unreadable input. JSON Lines (.jsonl) data are validated line by line.
import fs from 'node:fs';
import Ajv from 'ajv';
import addFormats from 'ajv-formats';

const [schemaPath, dataPath, ...extras] = process.argv.slice(2);
if (!schemaPath || !dataPath) { console.error('usage: validate.mjs SCHEMA DATA [EXTRA...]'); process.exit(2); }
let schema, docs;
try {
  schema = JSON.parse(fs.readFileSync(schemaPath, 'utf8'));
  const text = fs.readFileSync(dataPath, 'utf8');
  docs = dataPath.endsWith('.jsonl') ? text.split('\n').filter(l => l.trim()).map(l => JSON.parse(l)) : [JSON.parse(text)];
} catch (e) { console.error(`${dataPath}: ${e.message}`); process.exit(2); }
const ajv = new Ajv({ allErrors: true, strict: false });
addFormats(ajv);
for (const e of extras) ajv.addSchema(JSON.parse(fs.readFileSync(e, 'utf8')));
const validate = ajv.compile(schema);
let bad = 0;
docs.forEach((d, i) => {
  if (!validate(d)) {
    bad++;
    for (const err of validate.errors.slice(0, 20)) console.log(`${dataPath}[${i}]${err.instancePath}: ${err.message}`);
  }
});
if (bad === 0) console.log('valid');
process.exit(bad ? 1 : 0);
