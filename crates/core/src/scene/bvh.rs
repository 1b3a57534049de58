//! A bounding-volume hierarchy over the finite primitives of one instant.

use super::math::{Aabb, Ray};

#[derive(Clone, Copy, Debug)]
enum Node {
    Leaf { start: u32, count: u32 },
    Inner { left: u32, right: u32, axis: u8 },
}

/// Binary BVH with median splits on the longest centroid axis.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    bounds: Vec<Aabb>,
    nodes: Vec<Node>,
    /// Primitive indices, leaves point into this.
    items: Vec<usize>,
    /// Each item's own bounds (a leaf's bounds hold several items).
    item_bounds: Vec<Aabb>,
}

const LEAF_SIZE: usize = 2;

impl Bvh {
    /// Builds over `(item, bounds)` pairs.
    pub fn build(prims: &[(usize, Aabb)]) -> Bvh {
        let mut bvh = Bvh::default();
        if prims.is_empty() {
            return bvh;
        }
        let mut work: Vec<(usize, Aabb)> = prims.to_vec();
        bvh.build_node(&mut work);
        bvh
    }

    fn build_node(&mut self, prims: &mut [(usize, Aabb)]) -> u32 {
        let bounds = prims.iter().fold(Aabb::EMPTY, |b, (_, p)| b.union(p));
        let id = self.nodes.len() as u32;
        self.bounds.push(bounds);
        if prims.len() <= LEAF_SIZE {
            self.nodes.push(Node::Leaf {
                start: self.items.len() as u32,
                count: prims.len() as u32,
            });
            self.items.extend(prims.iter().map(|(i, _)| *i));
            self.item_bounds.extend(prims.iter().map(|(_, b)| *b));
            return id;
        }
        self.nodes.push(Node::Leaf { start: 0, count: 0 });
        let cb = prims.iter().fold(Aabb::EMPTY, |b, (_, p)| {
            let c = p.centre();
            b.union(&Aabb { min: c, max: c })
        });
        let ext = cb.max - cb.min;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        let mid = prims.len() / 2;
        prims.select_nth_unstable_by(mid, |a, b| a.1.centre()[axis].total_cmp(&b.1.centre()[axis]));
        let (l, r) = prims.split_at_mut(mid);
        let left = self.build_node(l);
        let right = self.build_node(r);
        self.nodes[id as usize] = Node::Inner {
            left,
            right,
            axis: axis as u8,
        };
        id
    }

    /// Appends to `out` every primitive whose own bounds pass `keep`, in the leaves
    /// reached through nodes whose bounds pass it.
    fn collect(&self, keep: impl Fn(&Aabb) -> bool, out: &mut Vec<usize>) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = [0u32; 64];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let n = stack[sp] as usize;
            if !keep(&self.bounds[n]) {
                continue;
            }
            match self.nodes[n] {
                Node::Leaf { start, count } => {
                    let range = start as usize..(start + count) as usize;
                    let leaf = self.items[range.clone()].iter().zip(&self.item_bounds[range]);
                    out.extend(leaf.filter(|(_, b)| keep(b)).map(|(&i, _)| i));
                }
                Node::Inner { left, right, .. } => {
                    stack[sp] = right;
                    stack[sp + 1] = left;
                    sp += 2;
                }
            }
        }
    }

    /// Appends to `out` every primitive whose bounds are not entirely outside one of the
    /// `planes` (point, inward normal): a conservative list for a beam of rays.
    pub fn collect_in_beam(&self, planes: &[(glam::DVec3, glam::DVec3)], out: &mut Vec<usize>) {
        self.collect(
            |b| {
                !planes.iter().any(|(o, n)| {
                    let p = glam::DVec3::select(n.cmpge(glam::DVec3::ZERO), b.max, b.min);
                    n.dot(p - *o) < 0.0
                })
            },
            out,
        );
    }

    /// Appends to `out` every primitive that the box `centre +- half`, swept from
    /// where it is along `dir` to infinity, may touch: a ray from `centre` against every
    /// bounds grown by `half` (the Minkowski sum), so conservative for all the rays
    /// leaving that box in direction `dir`.
    pub fn collect_swept(
        &self,
        centre: glam::DVec3,
        half: glam::DVec3,
        dir: glam::DVec3,
        out: &mut Vec<usize>,
    ) {
        let ray = Ray { origin: centre, dir };
        let inv = dir.recip();
        self.collect(
            |b| {
                let grown = Aabb {
                    min: b.min - half,
                    max: b.max + half,
                };
                grown.hit(&ray, inv, f64::INFINITY).is_some()
            },
            out,
        );
    }

    /// Calls `visit(item, t_max) -> new t_max` for every primitive whose bounds the ray
    /// enters before `t_max`; `visit` shrinks `t_max` as it finds hits, and returning a
    /// negative value stops the walk (any-hit queries).
    #[inline]
    pub fn walk(&self, ray: &Ray, mut t_max: f64, mut visit: impl FnMut(usize, f64) -> f64) {
        if self.nodes.is_empty() {
            return;
        }
        let inv = ray.dir.recip();
        let mut stack = [0u32; 64];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let n = stack[sp] as usize;
            if self.bounds[n].hit(ray, inv, t_max).is_none() {
                continue;
            }
            match self.nodes[n] {
                Node::Leaf { start, count } => {
                    for &item in &self.items[start as usize..(start + count) as usize] {
                        t_max = visit(item, t_max);
                        if t_max < 0.0 {
                            return;
                        }
                    }
                }
                Node::Inner { left, right, axis } => {
                    // Near child first (the left one holds the smaller centroids), so
                    // closest-hit queries shrink t_max early.
                    let (near, far) = if ray.dir[axis as usize] >= 0.0 {
                        (left, right)
                    } else {
                        (right, left)
                    };
                    stack[sp] = far;
                    stack[sp + 1] = near;
                    sp += 2;
                }
            }
        }
    }
}
