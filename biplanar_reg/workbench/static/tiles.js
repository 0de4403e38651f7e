// tiles.js — a small LRU cache of tile images. The viewer asks for tiles on every redraw; a
// missing tile starts loading and the viewer is told to redraw when it arrives, so panning and
// zooming never wait for the network.

export class TileCache {
  /** @param {() => void} onLoad called whenever a tile finishes loading */
  constructor(onLoad, capacity = 800) {
    this.onLoad = onLoad;
    this.capacity = capacity;
    this.entries = new Map(); // url -> {img, ready, failed}; Map order = recency
  }

  /** The loaded image for `url`, or null (and start loading it). */
  get(url) {
    const entry = this.entries.get(url);
    if (entry) {
      this.entries.delete(url); // re-insert: most recently used last
      this.entries.set(url, entry);
      return entry.ready ? entry.img : null;
    }
    this.load(url);
    return null;
  }

  /** The loaded image for `url` if cached; never starts a load (fallbacks while loading). */
  peek(url) {
    const entry = this.entries.get(url);
    return entry && entry.ready ? entry.img : null;
  }

  /** Number of tiles still loading (the e2e tests wait for 0). */
  pending() {
    let n = 0;
    for (const e of this.entries.values()) if (!e.ready && !e.failed) n += 1;
    return n;
  }

  load(url) {
    const img = new Image();
    const entry = { img, ready: false, failed: false };
    img.decoding = "async";
    img.onload = () => {
      entry.ready = true;
      this.onLoad();
    };
    img.onerror = () => {
      entry.failed = true; // kept in the cache so a broken tile is not re-requested every frame
    };
    img.src = url;
    this.entries.set(url, entry);
    this.evict();
  }

  evict() {
    while (this.entries.size > this.capacity) {
      const oldest = this.entries.keys().next().value;
      this.entries.delete(oldest);
    }
  }
}
