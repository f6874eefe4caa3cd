// Resolves when `map` has loaded its style and every tile in view and is not moving (polled every
// 250 ms after a repaint); rejects after 90 s. Shared by the pages of pmtiles.test.mjs and
// contours.test.mjs.
export function idle(map) {
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error('map not idle after 90 s')), 90000);
    const poll = setInterval(() => {
      if (map.loaded() && map.areTilesLoaded() && !map.isMoving()) { clearTimeout(timer); clearInterval(poll); resolve(); }
    }, 250);
    map.triggerRepaint();
  });
}
