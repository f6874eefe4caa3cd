//! Clipping a triangle to a box (Sutherland–Hodgman), each edge keeping what it
//! lies on, with crossings computed so that neighbours get the same bits.

/// A point being clipped: level coordinates (stage 1) or longitude/latitude
/// (stage 2), and its height.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Pt {
    pub(super) x: f64,
    pub(super) y: f64,
    pub(super) h: f64,
}

impl Pt {
    pub(super) fn key(self) -> (u64, u64) {
        (self.x.to_bits(), self.y.to_bits())
    }
}

/// What an edge of a clipped polygon lies on.
#[derive(Clone, Copy, Debug)]
pub(super) enum Support {
    /// The segment between two points fixed before clipping (an original edge, or a
    /// piece of the data's boundary between two stage-1 points).
    Segment(Pt, Pt),
    /// A clip line of this stage.
    Line(usize),
}

/// An axis-aligned clip line: `x ≥ v`, `x ≤ v`, `y ≥ v` or `y ≤ v`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Line {
    vertical: bool,
    v: f64,
    keep_greater: bool,
}

impl Line {
    fn inside(self, p: Pt) -> bool {
        let c = if self.vertical { p.x } else { p.y };
        if self.keep_greater {
            c >= self.v
        } else {
            c <= self.v
        }
    }
}

/// The four lines of a box `[x0, y0, x1, y1]`.
fn box_lines(b: [f64; 4]) -> [Line; 4] {
    [
        Line {
            vertical: true,
            v: b[0],
            keep_greater: true,
        },
        Line {
            vertical: false,
            v: b[1],
            keep_greater: true,
        },
        Line {
            vertical: true,
            v: b[2],
            keep_greater: false,
        },
        Line {
            vertical: false,
            v: b[3],
            keep_greater: false,
        },
    ]
}

/// Where a segment crosses a line, computed from its endpoints in a fixed order so
/// that every triangle (and every tile) sharing the segment gets the same bits.
fn crossing(a: Pt, b: Pt, line: Line) -> Pt {
    let (p, q) = if (a.x, a.y) <= (b.x, b.y) {
        (a, b)
    } else {
        (b, a)
    };
    let (pc, qc) = if line.vertical {
        (p.x, q.x)
    } else {
        (p.y, q.y)
    };
    let t = (line.v - pc) / (qc - pc);
    let other = |pv: f64, qv: f64| pv + t * (qv - pv);
    let h = other(p.h, q.h);
    if line.vertical {
        Pt {
            x: line.v,
            y: other(p.y, q.y),
            h,
        }
    } else {
        Pt {
            x: other(p.x, q.x),
            y: line.v,
            h,
        }
    }
}

/// The height of triangle `t`'s plane at `(x, y)`.
fn plane(t: &[Pt; 3], x: f64, y: f64) -> f64 {
    let [a, b, c] = t;
    let det = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
    let l1 = ((x - a.x) * (c.y - a.y) - (c.x - a.x) * (y - a.y)) / det;
    let l2 = ((b.x - a.x) * (y - a.y) - (x - a.x) * (b.y - a.y)) / det;
    a.h + l1 * (b.h - a.h) + l2 * (c.h - a.h)
}

/// Sutherland–Hodgman against one line, keeping each edge's support.
fn clip(poly: &[(Pt, Support)], lines: &[Line; 4], k: usize, tri: &[Pt; 3]) -> Vec<(Pt, Support)> {
    let line = lines[k];
    let mut out = Vec::with_capacity(poly.len() + 2);
    for i in 0..poly.len() {
        let (a, sup) = poly[i];
        let b = poly[(i + 1) % poly.len()].0;
        let (ina, inb) = (line.inside(a), line.inside(b));
        if ina {
            out.push((a, sup));
        }
        if ina != inb {
            let p = match sup {
                Support::Segment(p, q) => crossing(p, q, line),
                Support::Line(j) => {
                    // Two lines of one box meet at its corner, inside the triangle.
                    let (vx, hy) = if lines[j].vertical {
                        (lines[j].v, line.v)
                    } else {
                        (line.v, lines[j].v)
                    };
                    Pt {
                        x: vx,
                        y: hy,
                        h: plane(tri, vx, hy),
                    }
                }
            };
            out.push((p, if ina { Support::Line(k) } else { sup }));
        }
    }
    // A point met twice in a row (a vertex on the line, then its crossing there):
    // keep one, with the later copy's support — the earlier copy's edge has no
    // length, the later one's is the real next edge.
    let mut kept: Vec<(Pt, Support)> = Vec::with_capacity(out.len());
    for (p, sup) in out {
        match kept.last_mut() {
            Some(last) if last.0.key() == p.key() => last.1 = sup,
            _ => kept.push((p, sup)),
        }
    }
    while kept.len() > 1 && kept[0].0.key() == kept[kept.len() - 1].0.key() {
        kept.pop();
    }
    kept
}

pub(super) fn clip_box(poly: Vec<(Pt, Support)>, b: [f64; 4], tri: &[Pt; 3]) -> Vec<(Pt, Support)> {
    let lines = box_lines(b);
    let mut p = poly;
    for k in 0..4 {
        if p.len() < 3 {
            return Vec::new();
        }
        p = clip(&p, &lines, k, tri);
    }
    if p.len() < 3 { Vec::new() } else { p }
}
