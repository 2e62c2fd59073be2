// DOM helpers shared by the page (app.js) and the API documentation page (docs.js).
// Text goes in through textContent only: nothing a server or a file says is parsed as
// HTML.
'use strict';

window.spokemeshDom = Object.freeze({
  // The element with this id.
  $: (id) => document.getElementById(id),
  // <tag attrs...>children</tag>; attrs.text sets the text, attrs.class the class.
  el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === 'class') node.className = v; else if (k === 'text') node.textContent = v; else node.setAttribute(k, v);
    }
    for (const c of children) node.append(c);
    return node;
  },
});
