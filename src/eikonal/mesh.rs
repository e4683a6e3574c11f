//! Closed shapes from triangle meshes: a mesh's signed distance sampled on a grid, for
//! [`super::sdf::SdfGrid`] bounds (paper 002's scenes are meshes: Fig. 9's dragon).
//!
//! The distance is to the nearest triangle, found through a bounding-volume hierarchy. The sign
//! is the generalised winding number (Jacobson et al. 2013), `w(x) = Σ Ω_t(x) / 4π` over the
//! triangles' signed solid angles (Van Oosterom and Strackee 1983): 1 inside a closed mesh whose
//! faces are oriented outwards, 0 outside, and still near those values for meshes with small
//! holes, duplicated or badly joined faces; a node is inside where `w > ½`. Clusters of triangles
//! far from the node (beyond `FAR` times their radius) enter by their dipole term, the
//! first-order expansion of Barill et al. (2018), `Ω ≈ A·(c − x)/|c − x|³` with `A` the cluster's
//! summed area vector and `c` its area-weighted centre; nearer ones triangle by triangle.

use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Triangles per leaf of the hierarchy.
const LEAF: usize = 8;

/// A cluster farther than this many times its radius enters the winding number by its dipole
/// term (relative error about `1/FAR²` of its solid angle).
const FAR: f64 = 3.0;

/// A triangle mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<DVec3>,
    pub triangles: Vec<[usize; 3]>,
}

impl Mesh {
    /// A mesh of `triangles` (vertex indices, counter-clockwise seen from outside) over
    /// `vertices`; checked: indices in range, coordinates finite, some triangle with an area.
    pub fn new(vertices: Vec<DVec3>, triangles: Vec<[usize; 3]>) -> Result<Self, String> {
        if let Some((i, v)) = vertices.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(format!("vertex {i} {:?} is not finite", v.to_array()));
        }
        if let Some((i, t)) = triangles
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&k| k >= vertices.len()))
        {
            return Err(format!(
                "triangle {i} {t:?} names a vertex beyond the {} given",
                vertices.len()
            ));
        }
        let mesh = Mesh {
            vertices,
            triangles,
        };
        if !(0..mesh.triangles.len()).any(|t| mesh.area_vector(t).length() > 0.0) {
            return Err(format!(
                "no triangle has an area ({} triangles)",
                mesh.triangles.len()
            ));
        }
        Ok(mesh)
    }

    /// The mesh scaled by `scale` about the origin, then moved by `offset`.
    pub fn transformed(mut self, scale: f64, offset: DVec3) -> Self {
        for v in &mut self.vertices {
            *v = *v * scale + offset;
        }
        self
    }

    /// The corners of the box holding the mesh's triangles.
    pub fn extent(&self) -> (DVec3, DVec3) {
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for t in &self.triangles {
            for &k in t {
                lo = lo.min(self.vertices[k]);
                hi = hi.max(self.vertices[k]);
            }
        }
        (lo, hi)
    }

    fn corners(&self, t: usize) -> [DVec3; 3] {
        self.triangles[t].map(|k| self.vertices[k])
    }

    /// Half the cross product of two edges: the triangle's area times its outward normal.
    fn area_vector(&self, t: usize) -> DVec3 {
        let [a, b, c] = self.corners(t);
        0.5 * (b - a).cross(c - a)
    }

    /// The signed distance (negative inside) every `spacing` over the mesh's extent plus three
    /// nodes all round: origin, dims and samples (x fastest) for
    /// [`super::sdf::SdfGrid::from_samples`].
    pub fn signed_distance_grid(&self, spacing: f64) -> (DVec3, [usize; 3], Vec<f64>) {
        let (lo, hi) = self.extent();
        let pad = DVec3::splat(3.0 * spacing);
        let origin = lo - pad;
        let span = (hi + pad - origin) / spacing;
        let dims = [span.x, span.y, span.z].map(|s| s.ceil() as usize + 1);
        let bvh = Bvh::new(self);
        // row by row along x: the ball of radius d(x) about a node holds no triangle, so the next
        // node, `spacing` away, has the same winding number when d > spacing; it is computed
        // afresh only near the surface
        let rows: Vec<Vec<f64>> = (0..dims[1] * dims[2])
            .into_par_iter()
            .map(|row| {
                let (j, k) = (row % dims[1], row / dims[1]);
                let mut inside = false;
                let mut previous = f64::INFINITY;
                let mut stack = Vec::new();
                (0..dims[0])
                    .map(|i| {
                        let x = origin + DVec3::new(i as f64, j as f64, k as f64) * spacing;
                        // no farther than the previous node's nearest point
                        let d = bvh.distance(self, x, previous + spacing, &mut stack);
                        if i == 0 || previous <= spacing {
                            inside = bvh.winding_number(self, x, &mut stack) > 0.5;
                        }
                        previous = d;
                        if inside { -d } else { d }
                    })
                    .collect()
            })
            .collect();
        (origin, dims, rows.concat())
    }

    /// The signed distance at `x` (negative inside). Builds the hierarchy on every call: for a
    /// few points; [`Mesh::signed_distance_grid`] builds it once for many.
    pub fn signed_distance(&self, x: DVec3) -> f64 {
        Bvh::new(self).signed_distance(self, x)
    }

    /// The generalised winding number at `x`, triangle by triangle (the reference the
    /// hierarchy's is checked against).
    pub fn winding_number(&self, x: DVec3) -> f64 {
        (0..self.triangles.len())
            .map(|t| solid_angle(self.corners(t), x))
            .sum::<f64>()
            / (4.0 * PI)
    }
}

/// The signed solid angle triangle `[a, b, c]` subtends at `x`: positive seen from the side its
/// normal `(b − a) × (c − a)` points away from (Van Oosterom and Strackee 1983).
fn solid_angle([a, b, c]: [DVec3; 3], x: DVec3) -> f64 {
    let (a, b, c) = (a - x, b - x, c - x);
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    let det = a.dot(b.cross(c));
    let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
    2.0 * det.atan2(den)
}

/// The point of triangle `[a, b, c]` nearest `p` (Ericson, *Real-Time Collision Detection*,
/// Sec. 5.1.5).
fn closest_point([a, b, c]: [DVec3; 3], p: DVec3) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// A node of the hierarchy: its box, its triangles (`order[start..start + count]`, a leaf) or
/// its two children, and its dipole.
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    start: usize,
    count: usize,
    /// Children (inner nodes only).
    children: [usize; 2],
    /// Summed area vector, area-weighted centre, and the radius about it holding every vertex.
    area: DVec3,
    centre: DVec3,
    radius: f64,
}

/// A bounding-volume hierarchy over a mesh's triangles (median splits along the longest axis).
struct Bvh {
    nodes: Vec<Node>,
    order: Vec<usize>,
}

impl Bvh {
    fn new(mesh: &Mesh) -> Self {
        let centroid = |t: usize| {
            let [a, b, c] = mesh.corners(t);
            (a + b + c) / 3.0
        };
        let mut bvh = Bvh {
            nodes: Vec::new(),
            order: (0..mesh.triangles.len()).collect(),
        };
        // nodes still to split
        let mut todo = vec![bvh.leaf(mesh, 0, mesh.triangles.len())];
        while let Some(node) = todo.pop() {
            let Node {
                start,
                count,
                lo,
                hi,
                ..
            } = bvh.nodes[node];
            if count <= LEAF {
                continue;
            }
            let axis = (hi - lo).max_position();
            let half = count / 2;
            bvh.order[start..start + count].select_nth_unstable_by(half, |&p, &q| {
                centroid(p)[axis].total_cmp(&centroid(q)[axis])
            });
            let left = bvh.leaf(mesh, start, half);
            let right = bvh.leaf(mesh, start + half, count - half);
            let n = &mut bvh.nodes[node];
            n.children = [left, right];
            n.count = 0;
            todo.extend([left, right]);
        }
        bvh
    }

    /// A new leaf over `order[start..start + count]`: its box and dipole.
    fn leaf(&mut self, mesh: &Mesh, start: usize, count: usize) -> usize {
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        let (mut area, mut weighted, mut total) = (DVec3::ZERO, DVec3::ZERO, 0.0);
        for &t in &self.order[start..start + count] {
            let corners = mesh.corners(t);
            for v in corners {
                lo = lo.min(v);
                hi = hi.max(v);
            }
            let a = mesh.area_vector(t);
            area += a;
            weighted += (corners[0] + corners[1] + corners[2]) / 3.0 * a.length();
            total += a.length();
        }
        let centre = if total > 0.0 {
            weighted / total
        } else {
            (lo + hi) * 0.5
        };
        let radius = self.order[start..start + count]
            .iter()
            .flat_map(|&t| mesh.corners(t))
            .map(|v| (v - centre).length())
            .fold(0.0, f64::max);
        self.nodes.push(Node {
            lo,
            hi,
            start,
            count,
            children: [0; 2],
            area,
            centre,
            radius,
        });
        self.nodes.len() - 1
    }

    /// The distance from `x` to the nearest triangle, signed by the winding number.
    fn signed_distance(&self, mesh: &Mesh, x: DVec3) -> f64 {
        let mut stack = Vec::new();
        let d = self.distance(mesh, x, f64::INFINITY, &mut stack);
        if self.winding_number(mesh, x, &mut stack) > 0.5 {
            -d
        } else {
            d
        }
    }

    /// The distance from `x` to the nearest triangle, known to be at most `bound` (which prunes
    /// the search).
    /// `stack` is scratch (reused between queries: nothing is allocated once it has grown).
    fn distance(&self, mesh: &Mesh, x: DVec3, bound: f64, stack: &mut Vec<usize>) -> f64 {
        let box_distance = |n: &Node| (n.lo - x).max(x - n.hi).max(DVec3::ZERO).length_squared();
        // a hair above the bound, so that a triangle exactly at it is still found
        let mut best = (bound * (1.0 + 1e-9)).powi(2);
        stack.clear();
        stack.push(0);
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i];
            if box_distance(n) >= best {
                continue;
            }
            if n.count > 0 {
                for &t in &self.order[n.start..n.start + n.count] {
                    let corners = mesh.corners(t);
                    best = best.min((closest_point(corners, x) - x).length_squared());
                }
                continue;
            }
            // the nearer child last, so that it is searched first
            let [a, b] = n.children;
            let (da, db) = (box_distance(&self.nodes[a]), box_distance(&self.nodes[b]));
            if da < db {
                stack.extend([b, a]);
            } else {
                stack.extend([a, b]);
            }
        }
        best.sqrt()
    }

    /// The generalised winding number at `x`; `stack` as for [`Bvh::distance`].
    fn winding_number(&self, mesh: &Mesh, x: DVec3, stack: &mut Vec<usize>) -> f64 {
        let mut omega = 0.0;
        stack.clear();
        stack.push(0);
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i];
            let r = n.centre - x;
            let distance = r.length();
            if distance > FAR * n.radius {
                omega += n.area.dot(r) / (distance * distance * distance);
            } else if n.count > 0 {
                for &t in &self.order[n.start..n.start + n.count] {
                    omega += solid_angle(mesh.corners(t), x);
                }
            } else {
                stack.extend(n.children);
            }
        }
        omega / (4.0 * PI)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube `[−½, ½]³`, faces outwards (12 triangles).
    pub(crate) fn cube() -> Mesh {
        let vertices = (0..8)
            .map(|i| {
                DVec3::new(
                    (i & 1) as f64 - 0.5,
                    ((i >> 1) & 1) as f64 - 0.5,
                    ((i >> 2) & 1) as f64 - 0.5,
                )
            })
            .collect();
        // each face as a quad, counter-clockwise seen from outside
        let quads = [
            [0, 2, 3, 1], // z−
            [4, 5, 7, 6], // z+
            [0, 1, 5, 4], // y−
            [2, 6, 7, 3], // y+
            [0, 4, 6, 2], // x−
            [1, 3, 7, 5], // x+
        ];
        let triangles = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        Mesh::new(vertices, triangles).unwrap()
    }

    /// The exact signed distance of the unit cube.
    fn cube_distance(x: DVec3) -> f64 {
        let q = x.abs() - DVec3::splat(0.5);
        q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
    }

    #[test]
    fn a_cube_mesh_has_the_cube_distance() {
        let mesh = cube();
        let (origin, dims, samples) = mesh.signed_distance_grid(0.1);
        let mut worst: f64 = 0.0;
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let x = origin + DVec3::new(i as f64, j as f64, k as f64) * 0.1;
                    let d = samples[i + dims[0] * (j + dims[1] * k)];
                    worst = worst.max((d - cube_distance(x)).abs());
                }
            }
        }
        assert!(worst < 1e-12, "largest error {worst}");
        assert_eq!(dims, [17, 17, 17]);
    }

    #[test]
    fn winding_numbers_tell_inside_from_outside_even_through_a_hole() {
        let mut rng = crate::math::stream_rng(3, 0);
        let mesh = cube();
        let bvh = Bvh::new(&mesh);
        for _ in 0..500 {
            let x = DVec3::new(
                crate::math::uniform(&mut rng),
                crate::math::uniform(&mut rng),
                crate::math::uniform(&mut rng),
            ) * 3.0
                - DVec3::splat(1.5);
            let w = mesh.winding_number(x);
            let inside = cube_distance(x) < 0.0;
            assert!(
                (w - if inside { 1.0 } else { 0.0 }).abs() < 1e-9,
                "{x}: w = {w}"
            );
            // the hierarchy's, with its far-field terms, to a few parts in a thousand
            assert!((bvh.winding_number(&mesh, x, &mut Vec::new()) - w).abs() < 5e-3);
        }
        // one face (two triangles) missing: the centre is still inside (w = 5/6), a point
        // outside the open face still outside
        let mut open = cube();
        open.triangles.truncate(10);
        let w = open.winding_number(DVec3::ZERO);
        assert!((w - 5.0 / 6.0).abs() < 1e-9, "w = {w}");
        assert!(open.signed_distance(DVec3::ZERO) < 0.0);
        assert!(open.signed_distance(DVec3::new(0.0, 0.0, 0.8)) > 0.0);
    }

    #[test]
    fn bad_meshes_are_refused() {
        let v = vec![DVec3::ZERO, DVec3::X, DVec3::Y];
        assert!(
            Mesh::new(v.clone(), vec![[0, 1, 3]])
                .unwrap_err()
                .contains("vertex")
        );
        assert!(
            Mesh::new(v.clone(), vec![[0, 1, 1]])
                .unwrap_err()
                .contains("area")
        );
        let nan = vec![DVec3::ZERO, DVec3::X, DVec3::new(f64::NAN, 0.0, 0.0)];
        assert!(
            Mesh::new(nan, vec![[0, 1, 2]])
                .unwrap_err()
                .contains("finite")
        );
    }
}
