//! Geodesic waves (SPEC §2.2–2.3, paper §3.2.2): iso-lines of the local geodesic distance,
//! traced from triangle to adjacent triangle into polylines, and the rules that decide
//! whether a wave is usable.

use std::ops::Range;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::geodesic::LocalDistances;
use crate::mesh::topology::NO_FACE;
use crate::mesh::Topology;

/// Why a wave is not valid (SPEC §2.3). The first invalid wave stops a vertex's waves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WaveDefect {
    /// No edge crosses the iso-value (the component ends before it).
    Missing,
    /// The iso-line splits into several loops (paper Fig. 6 right).
    Branching,
    /// The iso-line reaches a mesh boundary or a non-manifold edge.
    Open,
    /// Fewer than 3 points.
    TooFewPoints,
    /// Flatness above `flat_max` (paper Fig. 6 left).
    NotFlat,
}

/// One traced wave: its points (in a [`WaveSet`]) and the quantities SPEC §2.4 needs.
#[derive(Debug, Clone, PartialEq)]
pub struct Wave {
    /// The iso-value `g_i`.
    pub distance: f64,
    points: Range<usize>,
    /// Number of separate polylines.
    pub loops: usize,
    /// Whether every polyline closed on itself.
    pub closed: bool,
    /// Centre `O_i`: the mean of the points.
    pub centre: DVec3,
    /// Unit normal `n_i`, oriented outward (SPEC §2.4).
    pub normal: DVec3,
    /// Mean distance to the wave plane over mean distance to the centre (SPEC §2.3).
    pub flatness: f64,
}

impl Wave {
    /// The SPEC §2.3 validity rules; `None` means valid.
    pub fn defect(&self, flat_max: f64) -> Option<WaveDefect> {
        // A wave cut by the boundary into several pieces counts as open: the boundary is
        // the cause.
        match self.loops {
            0 => Some(WaveDefect::Missing),
            _ if !self.closed => Some(WaveDefect::Open),
            1 if self.points.len() < 3 => Some(WaveDefect::TooFewPoints),
            1 if self.flatness > flat_max => Some(WaveDefect::NotFlat),
            1 => None,
            _ => Some(WaveDefect::Branching),
        }
    }
}

/// The waves of one source vertex, with their points in one shared buffer.
#[derive(Debug, Clone, Default)]
pub struct WaveSet {
    points: Vec<DVec3>,
    waves: Vec<Wave>,
}

impl WaveSet {
    pub fn clear(&mut self) {
        self.points.clear();
        self.waves.clear();
    }

    pub fn waves(&self) -> &[Wave] {
        &self.waves
    }

    /// The points of `wave`, in loop order.
    pub fn points(&self, wave: &Wave) -> &[DVec3] {
        &self.points[wave.points.clone()]
    }
}

/// Reusable per-thread tracing state.
#[derive(Debug, Clone)]
pub struct WaveTracer {
    stamp: Vec<u32>,
    generation: u32,
    /// Faces touching the settled disk as `(smallest, largest vertex distance, face)`, in
    /// order of the smallest.
    region: Vec<(f64, f64, u32)>,
    /// Sweep state: faces of `region[..entered]` whose largest distance is not below the
    /// last iso-value, i.e. the faces the last wave crossed.
    active: Vec<(f64, u32)>,
    entered: usize,
    last_g: f64,
    loop_spans: Vec<(Range<usize>, bool)>,
    backward: Vec<DVec3>,
}

/// What the tracer needs to know about the source vertex.
#[derive(Debug, Clone, Copy)]
pub struct Source {
    pub position: DVec3,
    /// Area-weighted vertex normal: orients waves where the winding cannot (SPEC §2.4).
    pub normal: DVec3,
}

impl WaveTracer {
    pub fn new(face_count: usize) -> Self {
        Self {
            stamp: vec![0; face_count],
            generation: 0,
            region: Vec::new(),
            active: Vec::new(),
            entered: 0,
            last_g: 0.0,
            loop_spans: Vec::new(),
            backward: Vec::new(),
        }
    }

    fn next_generation(&mut self) {
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.stamp.fill(0);
            self.generation = 1;
        }
    }

    /// Collects the faces around the settled disk of a new source. Settled vertices come in
    /// increasing distance, so the faces come sorted by their smallest vertex distance, and
    /// waves of increasing `g` find the faces they cross with one sweep (a face is crossed
    /// when its smallest distance is below `g` and its largest is not).
    pub fn set_region(
        &mut self,
        triangles: &[[u32; 3]],
        topology: &Topology,
        distances: &LocalDistances,
    ) {
        self.next_generation();
        self.region.clear();
        for &v in distances.settled() {
            for &f in topology.faces_of(v) {
                if self.stamp[f as usize] != self.generation {
                    self.stamp[f as usize] = self.generation;
                    let largest = triangles[f as usize]
                        .iter()
                        .map(|&u| distances.get(u))
                        .fold(0.0, f64::max);
                    self.region.push((distances.get(v), largest, f));
                }
            }
        }
        self.restart_sweep();
    }

    fn restart_sweep(&mut self) {
        self.active.clear();
        self.entered = 0;
        self.last_g = 0.0;
    }

    /// Advances the sweep to `g`: afterwards `active` holds exactly the faces crossed at `g`.
    fn sweep_to(&mut self, g: f64) {
        if g < self.last_g {
            self.restart_sweep();
        }
        self.last_g = g;
        while let Some(&(smallest, largest, f)) = self.region.get(self.entered) {
            if smallest >= g {
                break;
            }
            self.active.push((largest, f));
            self.entered += 1;
        }
        self.active.retain(|&(largest, _)| largest >= g);
    }

    /// Traces the iso-line at `g` (SPEC §2.2) and appends it to `set`.
    #[allow(clippy::too_many_arguments)]
    pub fn trace(
        &mut self,
        positions: &[DVec3],
        triangles: &[[u32; 3]],
        topology: &Topology,
        distances: &LocalDistances,
        source: Source,
        g: f64,
        set: &mut WaveSet,
    ) {
        self.sweep_to(g);
        self.next_generation();
        self.loop_spans.clear();
        let walk = Walk {
            positions,
            triangles,
            neighbours: &topology.faces.neighbour,
            distances,
            g,
        };
        let first = set.points.len();
        let mut consistent = true;
        for i in 0..self.active.len() {
            let f = self.active[i].1;
            if self.stamp[f as usize] == self.generation {
                continue;
            }
            let start = set.points.len();
            let (closed, agrees) = self.trace_loop(&walk, f, &mut set.points);
            consistent &= agrees;
            self.loop_spans.push((start..set.points.len(), closed));
        }
        let points = &set.points[first..];
        let wave = geometry(points, &self.loop_spans, first, consistent, source, g);
        set.waves.push(Wave {
            points: first..set.points.len(),
            ..wave
        });
    }

    /// Walks one polyline starting in face `f0`, leaving each face by its crossing edge that
    /// runs outside → inside in the face's winding, which keeps the inside of the disk on the
    /// left as seen from the outward side (SPEC §2.4). Returns whether it closed and whether
    /// every face it crossed agreed with that direction.
    fn trace_loop(&mut self, walk: &Walk, f0: u32, points: &mut Vec<DVec3>) -> (bool, bool) {
        self.stamp[f0 as usize] = self.generation;
        let start = points.len();
        let inside = walk.inside(f0);
        let crossing = |from_inside: bool| {
            (0..3)
                .find(|&k| inside[k] == from_inside && inside[(k + 1) % 3] != from_inside)
                .unwrap_or(0)
        };
        let (exit, entry) = (crossing(false), crossing(true));
        let stamps = (&mut self.stamp[..], self.generation);
        let (closed, forward) = walk.follow(stamps, f0, exit, points);
        if closed {
            return (true, forward);
        }
        // Open: walk back from f0 through its entry edge and prepend that part.
        self.backward.clear();
        let stamps = (&mut self.stamp[..], self.generation);
        let (_, backward) = walk.follow(stamps, f0, entry, &mut self.backward);
        points.splice(start..start, self.backward.iter().rev().copied());
        (false, forward && backward)
    }
}

/// Read-only context of one iso-line.
struct Walk<'a> {
    positions: &'a [DVec3],
    triangles: &'a [[u32; 3]],
    neighbours: &'a [[u32; 3]],
    distances: &'a LocalDistances<'a>,
    g: f64,
}

impl Walk<'_> {
    fn inside(&self, f: u32) -> [bool; 3] {
        self.triangles[f as usize].map(|v| self.distances.get(v) < self.g)
    }

    /// Follows the iso-line from face `f0` out through its edge `edge`, face by face, until
    /// it comes back to `f0` (closed), reaches a boundary or non-manifold edge, or meets a
    /// face already walked (open). Faces walked are stamped. Returns whether it closed and
    /// whether every face agreed with the winding of the one before.
    fn follow(
        &self,
        (stamp, generation): (&mut [u32], u32),
        f0: u32,
        edge: usize,
        out: &mut Vec<DVec3>,
    ) -> (bool, bool) {
        let (mut face, mut edge) = (f0, edge);
        let mut consistent = true;
        loop {
            out.push(self.iso_point(face, edge));
            let next = self.neighbours[face as usize][edge];
            if next == f0 {
                return (true, consistent);
            }
            if next == NO_FACE || stamp[next as usize] == generation {
                return (false, consistent);
            }
            stamp[next as usize] = generation;
            let (shared, agrees) = self.shared_edge(face, edge, next);
            consistent &= agrees;
            face = next;
            edge = self.other_crossing(face, shared);
        }
    }

    /// The iso-point on edge `k` of face `f`, interpolated from its inner end, so both faces
    /// of an edge produce the identical point.
    fn iso_point(&self, f: u32, k: usize) -> DVec3 {
        let t = self.triangles[f as usize];
        let (mut a, mut b) = (t[k], t[(k + 1) % 3]);
        if self.distances.get(a) >= self.g {
            std::mem::swap(&mut a, &mut b);
        }
        let (da, db) = (self.distances.get(a), self.distances.get(b));
        let s = (self.g - da) / (db - da);
        let (pa, pb) = (self.positions[a as usize], self.positions[b as usize]);
        pa + (pb - pa) * s
    }

    /// The index in `next` of the edge it shares with edge `k` of `face`, and whether `next`
    /// walks it in the opposite direction (consistent winding).
    fn shared_edge(&self, face: u32, k: usize, next: u32) -> (usize, bool) {
        let t = self.triangles[face as usize];
        let (a, b) = (t[k], t[(k + 1) % 3]);
        let n = self.triangles[next as usize];
        for j in 0..3 {
            let (c, d) = (n[j], n[(j + 1) % 3]);
            if (c, d) == (b, a) {
                return (j, true);
            }
            if (c, d) == (a, b) {
                return (j, false);
            }
        }
        (0, false)
    }

    /// The crossing edge of `f` other than `via` (a crossed triangle has exactly two).
    fn other_crossing(&self, f: u32, via: usize) -> usize {
        let inside = self.inside(f);
        (0..3)
            .find(|&k| k != via && inside[k] != inside[(k + 1) % 3])
            .unwrap_or(via)
    }
}

/// Centre, normal and flatness of a wave (SPEC §2.3–2.4). `spans` index the whole point
/// buffer; `points` starts at `offset` in it.
fn geometry(
    points: &[DVec3],
    spans: &[(Range<usize>, bool)],
    offset: usize,
    consistent: bool,
    source: Source,
    g: f64,
) -> Wave {
    let centre = points.iter().copied().sum::<DVec3>() / points.len().max(1) as f64;
    let mut area_normal = DVec3::ZERO;
    for (span, closed) in spans {
        let line = &points[span.start - offset..span.end - offset];
        for pair in line.windows(2) {
            area_normal += (pair[0] - centre).cross(pair[1] - centre);
        }
        if *closed && line.len() > 2 {
            area_normal += (line[line.len() - 1] - centre).cross(line[0] - centre);
        }
    }
    let mut normal = area_normal.normalize_or_zero();
    if normal == DVec3::ZERO {
        normal = source.normal;
    } else if !consistent && normal.dot(source.normal) < 0.0 {
        normal = -normal;
    }
    let (mut off_plane, mut radial) = (0.0, 0.0);
    for &p in points {
        off_plane += (p - centre).dot(normal).abs();
        radial += p.distance(centre);
    }
    Wave {
        distance: g,
        points: 0..0,
        loops: spans.len(),
        closed: spans.iter().all(|(_, closed)| *closed),
        centre,
        normal,
        flatness: if radial > 0.0 {
            off_plane / radial
        } else {
            0.0
        },
    }
}
