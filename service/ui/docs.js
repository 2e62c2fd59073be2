// /docs: the OpenAPI description served at /openapi.json, rendered as a readable page
// (operations with their parameters, bodies and answers; then the schemas). Text only
// through textContent: nothing of the description is parsed as HTML.
'use strict';

(() => {
  const { $, el } = window.spokemeshDom;
  // Paragraphs of plain text (blank-line separated), `code` spans kept as code.
  function prose(text) {
    const out = el('div');
    for (const para of String(text || '').split(/\n\s*\n/)) {
      if (!para.trim()) continue;
      const p = el('p');
      para.split(/(`[^`]+`)/).forEach((part) => {
        p.append(part.startsWith('`') && part.endsWith('`') && part.length > 1 ? el('code', { text: part.slice(1, -1) }) : part);
      });
      out.append(p);
    }
    return out;
  }
  const refName = (ref) => ref.split('/').pop();
  // A schema, briefly: a link for a $ref, else its type (and items / enum).
  function schemaSummary(schema) {
    if (!schema) return document.createTextNode('');
    if (schema.$ref) return el('a', { href: '#schema-' + refName(schema.$ref), text: refName(schema.$ref) });
    const span = el('span');
    if (schema.type === 'array') {
      span.append('array of ', schemaSummary(schema.items));
    } else if (schema.oneOf || schema.anyOf) {
      (schema.oneOf || schema.anyOf).forEach((s, i) => span.append(i ? ' | ' : '', schemaSummary(s)));
    } else {
      span.append(schema.type || 'object');
      if (schema.format) span.append(' (' + schema.format + ')');
      if (schema.enum) span.append(': ' + schema.enum.join(', '));
    }
    return span;
  }
  function parameterTable(parameters, doc) {
    const rows = parameters.map((p0) => {
      const p = p0.$ref ? resolve(doc, p0.$ref) : p0;
      return el('tr', {}, el('td', {}, el('code', { text: p.name })), el('td', { text: p.in }),
        el('td', { text: p.required ? 'required' : '' }), el('td', {}, schemaSummary(p.schema)),
        el('td', { text: p.description || '' }));
    });
    return el('table', {}, el('thead', {}, el('tr', {}, ...['name', 'in', '', 'type', 'description'].map((t) => el('th', { text: t })))),
      el('tbody', {}, ...rows));
  }
  function resolve(doc, ref) {
    return ref.replace(/^#\//, '').split('/').reduce((o, k) => (o ? o[k] : undefined), doc) || {};
  }
  function operation(doc, path, method, op) {
    const id = 'op-' + (op.operationId || method + path).replace(/[^A-Za-z0-9_-]/g, '_');
    const box = el('section', { class: 'op', id });
    box.append(el('h3', {}, el('span', { class: 'method ' + method, text: method }), el('code', { text: path })));
    if (op.summary) box.append(el('p', {}, el('b', { text: op.summary })));
    if (op.description) box.append(prose(op.description));
    if (op.parameters && op.parameters.length) box.append(el('h4', { text: 'Parameters' }), parameterTable(op.parameters, doc));
    if (op.requestBody) {
      box.append(el('h4', { text: 'Request body' + (op.requestBody.required ? ' (required)' : '') }));
      if (op.requestBody.description) box.append(prose(op.requestBody.description));
      const list = el('ul');
      for (const [type, media] of Object.entries(op.requestBody.content || {})) {
        list.append(el('li', {}, el('code', { text: type }), ': ', schemaSummary(media.schema)));
      }
      box.append(list);
    }
    if (op.responses) {
      box.append(el('h4', { text: 'Answers' }));
      const list = el('ul');
      for (const [code, r0] of Object.entries(op.responses)) {
        const r = r0.$ref ? resolve(doc, r0.$ref) : r0;
        const item = el('li', {}, el('b', { text: code }), ' ', r.description || '');
        for (const [type, media] of Object.entries(r.content || {})) item.append(' — ', el('code', { text: type }), ' ', schemaSummary(media.schema));
        list.append(item);
      }
      box.append(list);
    }
    return box;
  }

  async function main() {
    const response = await fetch('/openapi.json', { cache: 'no-store' });
    if (!response.ok) throw new Error('/openapi.json answered ' + response.status);
    const doc = await response.json();
    $('title').textContent = (doc.info && doc.info.title) || 'API';
    $('version').textContent = doc.info && doc.info.version ? 'version ' + doc.info.version : '';
    document.title = $('title').textContent;
    if (doc.info && doc.info.description) $('description').append(prose(doc.info.description));
    for (const [path, item] of Object.entries(doc.paths || {})) {
      for (const method of ['get', 'put', 'post', 'delete', 'patch']) {
        const op = item[method];
        if (!op) continue;
        if (item.parameters) op.parameters = [...item.parameters, ...(op.parameters || [])];
        const box = operation(doc, path, method, op);
        $('operations').append(box);
        $('toc').append(el('li', {}, el('a', { href: '#' + box.id }, el('span', { class: 'method ' + method, text: method }), ' ' + path)));
      }
    }
    for (const [name, schema] of Object.entries((doc.components && doc.components.schemas) || {})) {
      const box = el('section', { class: 'op', id: 'schema-' + name }, el('h3', { text: name }));
      if (schema.description) box.append(prose(schema.description));
      if (schema.properties) {
        const required = new Set(schema.required || []);
        const rows = Object.entries(schema.properties).map(([field, s]) => el('tr', {},
          el('td', {}, el('code', { text: field })), el('td', { text: required.has(field) ? 'required' : '' }),
          el('td', {}, schemaSummary(s)), el('td', { text: s.description || '' })));
        box.append(el('table', {}, el('tbody', {}, ...rows)));
      } else {
        box.append(el('p', {}, schemaSummary(schema)));
      }
      $('schemas').append(box);
    }
    $('docs-status').textContent = Object.keys(doc.paths || {}).length + ' paths, from /openapi.json';
  }
  main().catch((e) => { $('docs-status').textContent = 'Could not render the API description: ' + e.message; $('docs-status').className = 'error'; });
})();
