use glam::Vec3;

/// An axis-aligned box `[min, max]`, the domain of fields and kernel families.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
}

impl Aabb {
    /// A box from its corners (component-wise min and max are taken, so order does not matter).
    pub fn new(a: Vec3, b: Vec3) -> Self {
        Self {
            min: a.min(b),
            max: a.max(b),
        }
    }

    /// The unit cube `[0, 1]³`.
    pub const UNIT: Aabb = Aabb {
        min: Vec3::ZERO,
        max: Vec3::ONE,
    };

    /// Edge lengths.
    pub fn size(&self) -> Vec3 {
        self.max - self.min
    }

    /// Centre point.
    pub fn centre(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }

    /// Whether `p` lies inside or on the boundary.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// The nearest point of the box to `p`.
    pub fn clamp(&self, p: Vec3) -> Vec3 {
        p.clamp(self.min, self.max)
    }

    /// The box grown by `margin` on every side.
    pub fn expand(&self, margin: f32) -> Aabb {
        Aabb {
            min: self.min - Vec3::splat(margin),
            max: self.max + Vec3::splat(margin),
        }
    }

    /// Smallest box holding both.
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// Maps `p` to local coordinates in `[0, 1]³` (0 at `min`, 1 at `max`); a degenerate axis maps to 0.
    pub fn to_local(&self, p: Vec3) -> Vec3 {
        let size = self.size();
        let inv = Vec3::select(size.cmpgt(Vec3::ZERO), size.recip(), Vec3::ZERO);
        (p - self.min) * inv
    }

    /// Whether both corners are finite and `min <= max` on every axis.
    pub fn is_valid(&self) -> bool {
        self.min.is_finite() && self.max.is_finite() && self.min.cmple(self.max).all()
    }
}
