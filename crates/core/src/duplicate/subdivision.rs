//! Whether a mesh is one subdivision step of another: its triangles each split in four
//! (midpoint, Loop's, the butterfly's), told by connectivity alone, or a Catmull–Clark step
//! (Blender's Subdivision Surface, OpenSubdiv) with its quads triangulated, told by counts.
//!
//! A smoothing subdivision is another asset (#38), but one step of it on a mesh of a few
//! thousand vertices moves the surface less, in lengths of the coarser mesh's edges, than a
//! quadric simplification does (`docs/results/duplicates/`): no distance tells the two
//! apart. Their meshes do. A split's every coarse triangle becomes a middle triangle on its
//! edges' new vertices and three corners, each at one of its old vertices; a simplification
//! leaves no such pattern behind. A split that keeps the surface (midpoint) is
//! `identical_geometry`, decided before this is asked.

use rustc_hash::FxHashMap as HashMap;

use crate::mesh::topology::{face_neighbours, NO_FACE};

/// The share of old vertices, and of middles on an old vertex, by which a split may miss
/// its counts: a piece of the mesh joined to the rest only by edges of more than two faces
/// (CAPOD's vases m63 and m65 have a few) may be labelled either way, ~20 of 30 000 middles.
const ASTRAY: f64 = 0.01;

/// A fine mesh as [`assign`] walks it: its triangles, the face across each of their edges
/// ([`face_neighbours`]), and whether an edge without one is on the boundary.
struct Mesh<'a> {
    fine: &'a [[u32; 3]],
    across: &'a [[u32; 3]],
    boundary: &'a dyn Fn(u32, u32) -> bool,
}

/// A face of a split mesh: the middle of its coarse triangle, or the corner at an old vertex.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Middle,
    Corner(u32),
}

/// Whether `fine` is a mesh of `coarse` = (vertices, triangles) with every triangle split in
/// four: four times the triangles, each face a middle or a corner consistently with its
/// neighbours, a quarter of them middles, as many old vertices as the coarse mesh has, and
/// no middle on one (the last three up to [`ASTRAY`]). Linear in the triangles.
pub fn is_split(fine: &[[u32; 3]], (vertices, triangles): (usize, usize)) -> bool {
    if triangles == 0 || fine.len() != 4 * triangles {
        return false;
    }
    let across = face_neighbours(fine).neighbour;
    // Edges without one face across: on the boundary (one face) or of more than two.
    let mut lonely: HashMap<(u32, u32), usize> = HashMap::default();
    for (t, across) in fine.iter().zip(&across) {
        for k in (0..3).filter(|&k| across[k] == NO_FACE) {
            let (u, v) = (t[k], t[(k + 1) % 3]);
            *lonely.entry((u.min(v), u.max(v))).or_default() += 1;
        }
    }
    let boundary = |u: u32, v: u32| lonely.get(&(u.min(v), u.max(v))) == Some(&1);
    let mesh = Mesh {
        fine,
        across: &across,
        boundary: &boundary,
    };
    let mut roles: Vec<Option<Role>> = vec![None; fine.len()];
    // A face with no face across any edge (its edges all of more than two faces) is not
    // constrained by its neighbours: labelled last, from its vertices' labels.
    let (alone, joined): (Vec<usize>, Vec<usize>) =
        (0..fine.len()).partition(|&f| across[f].iter().all(|&g| g == NO_FACE));
    for f in joined {
        if roles[f].is_some() {
            continue;
        }
        // The first face of a piece not yet seen is its middle or a corner at one of its
        // vertices: each guess decides the whole piece, or meets a contradiction.
        let [a, b, c] = fine[f];
        let guesses = [
            Role::Middle,
            Role::Corner(a),
            Role::Corner(b),
            Role::Corner(c),
        ];
        if !guesses
            .into_iter()
            .any(|role| assign(&mesh, &mut roles, (f, role)))
        {
            return false;
        }
    }
    let count = fine.iter().flatten().max().map_or(0, |&v| v as usize + 1);
    let mut old = vec![false; count];
    for role in &roles {
        if let Some(Role::Corner(v)) = role {
            old[*v as usize] = true;
        }
    }
    for f in alone {
        roles[f] = Some(match fine[f].into_iter().find(|&v| old[v as usize]) {
            Some(v) => Role::Corner(v),
            None => Role::Middle,
        });
    }
    let (mut middles, mut astray) = (0, 0);
    for (t, role) in fine.iter().zip(&roles) {
        if *role == Some(Role::Middle) {
            middles += 1;
            astray += usize::from(t.iter().any(|&v| old[v as usize]));
        }
    }
    let near = |x: usize, y: usize| x.abs_diff(y) as f64 <= ASTRAY * y as f64;
    near(4 * middles, fine.len())
        && near(old.iter().filter(|&&o| o).count(), vertices)
        && astray as f64 <= ASTRAY * middles as f64
}

/// Whether a mesh of `fine` = (vertices, triangles) has the counts of one Catmull–Clark step
/// of `coarse` (its vertex count and triangles), its quads triangulated: a vertex per old
/// vertex, per edge and per triangle, and six triangles per triangle, exactly.
///
/// Counts alone, because the triangulation hides the quads: each may be cut along either
/// diagonal, so no local pattern is left to walk as [`is_split`] does, and recovering the quads
/// is a search. Exact counts are what a simplification meets only by coincidence: a sixth of
/// the triangles to the triangle, and (the vertex count follows on a closed mesh) the same
/// Euler characteristic. A linear step of the same topology (Blender's "Simple") keeps the
/// surface, which the caller checks.
pub fn is_catmull_clark(
    (vertices, triangles): (usize, usize),
    coarse: (usize, &[[u32; 3]]),
) -> bool {
    let (coarse_vertices, coarse) = coarse;
    let edges: rustc_hash::FxHashSet<(u32, u32)> = coarse
        .iter()
        .flat_map(|t| [0, 1, 2].map(|k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
        .collect();
    !coarse.is_empty()
        && triangles == 6 * coarse.len()
        && vertices == coarse_vertices + edges.len() + coarse.len()
}

/// Gives face `f` its `role` and its piece what follows (a middle's three neighbours are
/// corners at their vertex off the shared edge; a corner's neighbour across the edge off its
/// old vertex is the middle, across the other two a corner at the same vertex). Undoes what
/// it gave and answers false at a contradiction.
fn assign(mesh: &Mesh, roles: &mut [Option<Role>], (f, role): (usize, Role)) -> bool {
    let Mesh {
        fine,
        across,
        boundary,
    } = mesh;
    let mut given = Vec::new();
    let mut pending = vec![(f, role)];
    let consistent = 'walk: {
        while let Some((f, role)) = pending.pop() {
            match roles[f] {
                Some(r) if r == role => continue,
                Some(_) => break 'walk false,
                None => {
                    roles[f] = Some(role);
                    given.push(f);
                }
            }
            let t = fine[f];
            for k in 0..3 {
                let (u, v, g) = (t[k], t[(k + 1) % 3], across[f][k]);
                let outer = matches!(role, Role::Corner(old) if u == old || v == old);
                if g == NO_FACE {
                    // Only a corner's outer edge may be on the boundary. An edge of more than
                    // two faces (a coarse mesh's doubled triangles split into doubled
                    // middles) says nothing: the counts must still hold.
                    if !outer && boundary(u, v) {
                        break 'walk false;
                    }
                    continue;
                }
                let implied = match role {
                    Role::Corner(old) if outer => Role::Corner(old),
                    Role::Corner(_) => Role::Middle,
                    Role::Middle => match fine[g as usize].iter().find(|&&w| w != u && w != v) {
                        Some(&w) => Role::Corner(w),
                        None => break 'walk false,
                    },
                };
                pending.push((g as usize, implied));
            }
        }
        true
    };
    if !consistent {
        for f in given {
            roles[f] = None;
        }
    }
    consistent
}

#[cfg(test)]
mod tests {
    use super::{is_catmull_clark, is_split};
    use std::collections::HashMap;

    /// An octahedron, closed; a square of two triangles, with a boundary; and the
    /// octahedron with a triangle doubled, whose edges then have three faces.
    fn meshes() -> [(usize, Vec<[u32; 3]>); 3] {
        let octahedron = vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        let mut doubled = octahedron.clone();
        doubled.push([4, 2, 0]);
        [
            (6, octahedron),
            (4, vec![[0, 1, 2], [0, 2, 3]]),
            (6, doubled),
        ]
    }

    /// Every triangle split in four at new vertices on its edges.
    fn split(vertices: usize, triangles: &[[u32; 3]]) -> Vec<[u32; 3]> {
        let mut middles = HashMap::new();
        let mut middle = |a: u32, b: u32| {
            let next = (vertices + middles.len()) as u32;
            *middles.entry((a.min(b), a.max(b))).or_insert(next)
        };
        triangles
            .iter()
            .flat_map(|&[a, b, c]| {
                let (ab, bc, ca) = (middle(a, b), middle(b, c), middle(c, a));
                [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
            })
            .collect()
    }

    #[test]
    fn a_split_mesh_is_one_and_twice_split_is_one_of_the_once_split() {
        for (vertices, triangles) in meshes() {
            let once = split(vertices, &triangles);
            assert!(is_split(&once, (vertices, triangles.len())));
            let once_vertices = *once.iter().flatten().max().unwrap() as usize + 1;
            let twice = split(once_vertices, &once);
            assert!(is_split(&twice, (once_vertices, once.len())));
            assert!(!is_split(&twice, (vertices, triangles.len())));
            // Not a split of a mesh with other counts, nor a mesh of itself.
            assert!(!is_split(&once, (vertices + 1, triangles.len())));
            assert!(!is_split(&triangles, (vertices, triangles.len())));
        }
    }

    #[test]
    fn one_flipped_edge_or_reordered_pieces_are_no_split() {
        let (vertices, triangles) = meshes()[0].clone();
        let once = split(vertices, &triangles);
        // The edge between the first middle triangle and the corner at its first edge,
        // flipped: the same counts, no longer a split.
        let mut flipped = once.clone();
        let [a, ab, ca] = flipped[0];
        let [_, bc, _] = flipped[3];
        flipped[0] = [a, ab, bc];
        flipped[3] = [a, bc, ca];
        assert!(!is_split(&flipped, (vertices, triangles.len())));
        // The triangles' order does not matter.
        let mut shuffled = once.clone();
        shuffled.reverse();
        shuffled.iter_mut().for_each(|t| t.rotate_left(1));
        assert!(is_split(&shuffled, (vertices, triangles.len())));
    }

    /// One Catmull–Clark step's topology: per triangle a face point and three quads on its
    /// edges' points, each quad cut along the diagonal `cut` picks.
    fn catmull_clark(
        vertices: usize,
        triangles: &[[u32; 3]],
        cut: impl Fn(usize) -> bool,
    ) -> Vec<[u32; 3]> {
        let mut points = HashMap::new();
        let mut point = |a: u32, b: u32| {
            let next = (vertices + points.len()) as u32;
            *points.entry((a.min(b), a.max(b))).or_insert(next)
        };
        let edge_points: Vec<[u32; 3]> = triangles
            .iter()
            .map(|&[a, b, c]| [point(a, b), point(b, c), point(c, a)])
            .collect();
        let first_face = (vertices + points.len()) as u32;
        let mut quads = 0;
        let mut out = Vec::new();
        for (f, (&[a, b, c], &[ab, bc, ca])) in triangles.iter().zip(&edge_points).enumerate() {
            let centre = first_face + f as u32;
            for [o, next, previous] in [[a, ab, ca], [b, bc, ab], [c, ca, bc]] {
                out.extend(if cut(quads) {
                    [[o, next, centre], [o, centre, previous]]
                } else {
                    [[o, next, previous], [next, centre, previous]]
                });
                quads += 1;
            }
        }
        out
    }

    #[test]
    fn catmull_clark_is_told_by_its_counts_whatever_the_diagonals() {
        for (vertices, triangles) in meshes() {
            let coarse = (vertices, &triangles[..]);
            let cuts: [fn(usize) -> bool; 3] = [|_| true, |_| false, |q| q % 3 == 1];
            for cut in cuts {
                let fine = catmull_clark(vertices, &triangles, cut);
                let fine_vertices = *fine.iter().flatten().max().unwrap() as usize + 1;
                assert!(is_catmull_clark((fine_vertices, fine.len()), coarse));
                // One vertex more or less, or a triangle fewer, is not one.
                assert!(!is_catmull_clark((fine_vertices - 1, fine.len()), coarse));
                assert!(!is_catmull_clark((fine_vertices, fine.len() - 2), coarse));
                // Nor is a split in four, nor the mesh itself.
                assert!(!is_split(&fine, (vertices, triangles.len())));
            }
            let once = split(vertices, &triangles);
            let once_vertices = *once.iter().flatten().max().unwrap() as usize + 1;
            assert!(!is_catmull_clark((once_vertices, once.len()), coarse));
            assert!(!is_catmull_clark((vertices, triangles.len()), coarse));
        }
    }
}
