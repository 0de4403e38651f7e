// dom.js — building the page's elements.

/**
 * A new `tag` element: `attrs` become attributes, except `dataset` (an object merged into the
 * element's data-* attributes) and `on<event>` (a listener); `children` are appended.
 */
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "dataset") Object.assign(node.dataset, v);
    else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else node.setAttribute(k, v);
  }
  node.append(...children);
  return node;
}
