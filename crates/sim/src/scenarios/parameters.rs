//! What scenario scenes are drawn from: the [`Scenario`] kinds, the `rest` arrangements
//! ([`RestVariant`]) and every range and list a scenario draws from ([`ScenarioParameters`]).

use serde::{Deserialize, Serialize};

use crate::materials::{METAL, MOVI_FLOOR, RUBBER};
use crate::scene::{FloorSpec, Material};
use crate::shapes::ShapeKind;
use crate::{Result, SimError};

/// One behaviour a scenario scene isolates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Scenario {
    /// Objects at rest from frame 0: single objects, box towers, settled piles.
    Rest,
    /// One object dropped with random attitude and spin, bouncing and settling.
    Drop,
    /// Objects resting on the floor launched horizontally; friction stops them.
    Slide,
    /// Two objects thrown at each other, in the air or along the floor.
    Collide,
    /// A small box tower hit by a thrown object (the last object of the scene).
    StackHit,
    /// Objects resting on the floor pushed by a kinematic pusher (the last object of the
    /// scene) following a random smooth path through them.
    Push,
    /// Round objects (cylinder, cone, mug) lying on their side, set rolling along the floor;
    /// rapier slows them down and stops many within the scene.
    Roll,
}

impl Scenario {
    /// The scenarios `physics-mix` draws from, in its order: all but `push`, whose kinematic
    /// pusher is an input the mix's models are not trained to take.
    pub const ALL: [Scenario; 5] = [
        Scenario::Rest,
        Scenario::Drop,
        Scenario::Slide,
        Scenario::Collide,
        Scenario::StackHit,
    ];

    /// Name as used on the command line and in manifests.
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Rest => "rest",
            Scenario::Drop => "drop",
            Scenario::Slide => "slide",
            Scenario::Collide => "collide",
            Scenario::StackHit => "stack-hit",
            Scenario::Push => "push",
            Scenario::Roll => "roll",
        }
    }

    /// The scenario of a name written by [`Scenario::name`].
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .chain([Scenario::Push, Scenario::Roll])
            .find(|s| s.name() == name)
    }
}

/// Arrangements of the `rest` scenario.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestVariant {
    /// One to `rest_singles` objects of any shape, each alone on the floor.
    Single,
    /// A tower of cubes.
    Tower,
    /// A few objects dropped onto each other and settled.
    Pile,
}

impl RestVariant {
    /// Name recorded as the scene's variant.
    pub fn name(self) -> &'static str {
        match self {
            RestVariant::Single => "single",
            RestVariant::Tower => "tower",
            RestVariant::Pile => "pile",
        }
    }
}

/// Where scenario objects get their contact materials from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Materials {
    /// Kubric's metal or rubber, as in MOVi-B (friction, restitution and density move
    /// together).
    #[default]
    Kubric,
    /// Friction, restitution and density drawn independently and uniformly per object
    /// ([`MaterialRanges::UNIFORM`]).
    Uniform,
}

impl Materials {
    /// Name as on the command line (`kubric`, `uniform`).
    pub fn name(self) -> &'static str {
        match self {
            Materials::Kubric => "kubric",
            Materials::Uniform => "uniform",
        }
    }
}

/// Ranges of contact materials drawn per object, each coefficient independently and uniformly
/// (so that friction, restitution and mass vary separately, unlike Kubric's two materials,
/// in which they move together).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MaterialRanges {
    /// Friction coefficient range (combined with the floor's 0.3 by multiplication).
    pub friction: [f32; 2],
    /// Restitution coefficient range, within `[0, 1]`.
    pub restitution: [f32; 2],
    /// Density range, kilograms per cubic metre of the scene's units.
    pub density: [f32; 2],
}

impl MaterialRanges {
    /// The ranges `--materials uniform` draws from: friction 0.1-1.0, restitution 0.05-0.8,
    /// density 0.5-3.0. They hold both of Kubric's materials (metal 0.4 / 0.3 / 2.7, rubber
    /// 0.8 / 0.7 / 1.1) and the values users commonly send (wood, plastic, steel-like).
    pub const UNIFORM: Self = Self {
        friction: [0.1, 1.0],
        restitution: [0.05, 0.8],
        density: [0.5, 3.0],
    };

    /// Draws one material.
    pub fn draw<R: rand::Rng + ?Sized>(&self, rng: &mut R) -> Material {
        let u = |rng: &mut R, r: [f32; 2]| r[0] + (r[1] - r[0]) * rng.random::<f32>();
        Material {
            friction: u(rng, self.friction),
            restitution: u(rng, self.restitution),
            density: u(rng, self.density),
        }
    }

    fn validate(&self) -> Result<()> {
        let ordered = |r: [f32; 2], lo: f32, hi: f32| {
            r[0].is_finite() && r[1].is_finite() && lo <= r[0] && r[0] <= r[1] && r[1] <= hi
        };
        if ordered(self.friction, 0.0, f32::INFINITY)
            && ordered(self.restitution, 0.0, 1.0)
            && ordered(self.density, f32::MIN_POSITIVE, f32::INFINITY)
        {
            Ok(())
        } else {
            Err(SimError::Invalid(format!(
                "scenario parameters: material ranges must be ordered, friction >= 0, restitution in [0, 1], density > 0 (got {self:?})"
            )))
        }
    }
}

/// Parameters of the scenario generators, recorded in the manifest. Ranges `[a, b]` are
/// drawn uniformly (integers inclusive).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScenarioParameters {
    /// Scenarios drawn uniformly per scene (one entry for a single-scenario generator).
    pub scenarios: Vec<Scenario>,
    /// Shapes drawn uniformly; `shape_id` indexes this list.
    pub shapes: Vec<ShapeKind>,
    /// Uniform scale range of the unit shapes.
    pub scale: [f32; 2],
    /// Materials drawn uniformly: (name, material). Unused when `material_ranges` is set.
    pub materials: Vec<(String, Material)>,
    /// When set, every object draws its friction, restitution and density independently and
    /// uniformly from these ranges instead of picking one of `materials`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub material_ranges: Option<MaterialRanges>,
    /// The floor.
    pub floor: FloorSpec,
    /// Gravity, metres per second squared.
    pub gravity: [f32; 3],
    /// Physics steps run before frame 0 in `rest` and `stack-hit` scenes.
    pub settle_steps: u32,
    /// Longest pre-settling of objects placed on the floor or on a pile, physics steps.
    pub presettle_max_steps: u32,
    /// `rest` arrangements drawn uniformly.
    pub rest_variants: Vec<RestVariant>,
    /// Objects of a `rest` single scene.
    pub rest_singles: [usize; 2],
    /// Cubes of a `rest` tower.
    pub tower_boxes: [usize; 2],
    /// Uniform scale range (side, metres) of a `rest` tower's cubes; by default `scale`'s.
    pub tower_scale: [f32; 2],
    /// Largest horizontal offset of a tower box from the one below, per axis, metres.
    pub tower_offset: f32,
    /// Largest yaw of a tower box relative to the tower, radians.
    pub tower_yaw: f32,
    /// Objects of a `rest` pile.
    pub pile_objects: [usize; 2],
    /// Shapes of objects that start at rest (`rest` singles): every shape but the torus knot,
    /// which rapier never brings to rest on the floor (it creeps at about 3 cm/s).
    pub rest_shapes: Vec<ShapeKind>,
    /// Shapes of piles and of objects launched along the floor: `rest_shapes` without the
    /// sphere, which rolls instead of sliding or settling.
    pub floor_shapes: Vec<ShapeKind>,
    /// Height of a dropped object's lowest point at release, metres.
    pub drop_height: [f32; 2],
    /// Largest spin of a dropped object, radians per second (uniform in magnitude, uniform
    /// direction).
    pub drop_spin: f32,
    /// Objects of a `slide` scene (parallel lanes 2.5 m apart, one direction).
    pub slide_objects: [usize; 2],
    /// Launch speed of sliding objects, m/s, capped so that friction alone stops the object
    /// within `slide_stop_time`.
    pub slide_speed: [f32; 2],
    /// Longest stopping time under friction alone `v / (mu_object mu_floor |g|)`, seconds.
    pub slide_stop_time: f32,
    /// Objects of a `roll` scene (lanes 3 m apart across the rolling direction).
    pub roll_objects: [usize; 2],
    /// Shapes of a `roll` scene: round ones that roll on their side.
    pub roll_shapes: Vec<ShapeKind>,
    /// Initial rolling speed of the centre of a `roll` object, m/s (its spin about its axis
    /// is this speed over the centre's height, as for rolling without slipping).
    pub roll_speed: [f32; 2],
    /// Probability that a `collide` scene is thrown in the air rather than along the floor.
    pub collide_air_fraction: f32,
    /// Speed of each object towards the other in `collide`, m/s (horizontal).
    pub collide_speed: [f32; 2],
    /// Time from release to the impact of the centres in the air variant, seconds.
    pub collide_air_time: [f32; 2],
    /// Clearance of both objects' lowest points above the floor at the air impact, metres.
    pub collide_air_clearance: [f32; 2],
    /// Sideways offset of the two aim points, as a fraction of the sum of the objects'
    /// bounding radii (air) or half-widths across the approach (floor).
    pub collide_offset: f32,
    /// Gap between the two objects along the approach direction at the start of the floor
    /// variant, metres. Each object is launched at least 1.2 times as fast as friction alone
    /// needs to stop it within half the gap, `sqrt(mu_object mu_floor |g| gap)`.
    pub collide_floor_gap: [f32; 2],
    /// Largest spin of objects thrown in the air, radians per second.
    pub collide_spin: f32,
    /// Cubes of a `stack-hit` tower.
    pub stack_boxes: [usize; 2],
    /// Scale of the `stack-hit` tower's cubes (smaller than MOVi-B's, so the thrown object
    /// is heavy enough to knock the tower over rather than bounce off).
    pub stack_scale: [f32; 2],
    /// Scale of the thrown object.
    pub projectile_scale: [f32; 2],
    /// Launch speed of the thrown object, m/s.
    pub projectile_speed: [f32; 2],
    /// Distance from the tower's circumscribed circle to the thrown object's bounding sphere at
    /// launch, metres.
    pub projectile_distance: f32,
    /// Aim height as a fraction of the tower height.
    pub projectile_aim: [f32; 2],
    /// Objects of a `push` scene (on the floor, in a chain the pusher's path runs through).
    pub push_objects: [usize; 2],
    /// Gap between the bounding circles of consecutive pushed objects, metres.
    pub push_gap: [f32; 2],
    /// Largest turn of the chain's direction at each pushed object, radians.
    pub push_turn: f32,
    /// Largest sideways offset of the path from a pushed object's centre, as a fraction of its
    /// bounding radius.
    pub push_lateral: f32,
    /// Edge of the pusher cube, metres.
    pub pusher_scale: [f32; 2],
    /// Gap between the pusher's bottom face and the floor, metres.
    pub push_clearance: f32,
    /// Gap between the bounding circles of the pusher and the first object at the start,
    /// metres.
    pub push_approach: [f32; 2],
    /// Cruise speed of the pusher along its path, m/s.
    pub push_speed: [f32; 2],
    /// Time over which the pusher's speed ramps up linearly from rest, seconds.
    pub push_ramp: f32,
    /// Length of the path beyond the last object's bounding circle, metres (longer than the
    /// pusher travels in a scene, so it never stops).
    pub push_tail: f32,
    /// Largest deviation of the pusher's velocity from its path's, m/s per horizontal axis:
    /// every frame adds a velocity drawn uniformly in `[-push_jitter, push_jitter]` per axis to
    /// its path's for that frame (the position offsets accumulate), drawn afresh each frame, so
    /// from one frame to the next the velocity changes by up to twice this, as a planner that
    /// picks a new pusher velocity at every step does. 0 (the default) keeps the smooth path
    /// and draws nothing.
    pub push_jitter: f32,
}

impl ScenarioParameters {
    /// The defaults for scenes of `scenarios` (drawn uniformly per scene): MOVi-B shapes,
    /// scale, materials, floor and gravity.
    pub fn new(scenarios: Vec<Scenario>) -> Self {
        let rest_shapes: Vec<ShapeKind> = ShapeKind::MOVI_B
            .iter()
            .copied()
            .filter(|k| *k != ShapeKind::TorusKnot)
            .collect();
        let floor_shapes = rest_shapes
            .iter()
            .copied()
            .filter(|k| *k != ShapeKind::Sphere)
            .collect();
        Self {
            scenarios,
            shapes: ShapeKind::MOVI_B.to_vec(),
            scale: [0.7, 1.4],
            tower_scale: [0.7, 1.4],
            materials: vec![("metal".into(), METAL), ("rubber".into(), RUBBER)],
            material_ranges: None,
            floor: MOVI_FLOOR,
            gravity: [0.0, 0.0, -10.0],
            settle_steps: 720,
            presettle_max_steps: 2400,
            rest_shapes,
            rest_variants: vec![RestVariant::Single, RestVariant::Tower, RestVariant::Pile],
            rest_singles: [1, 3],
            tower_boxes: [2, 6],
            tower_offset: 0.003,
            tower_yaw: 0.05,
            pile_objects: [2, 4],
            floor_shapes,
            drop_height: [0.5, 3.0],
            drop_spin: 4.0,
            slide_objects: [1, 3],
            slide_speed: [1.0, 5.0],
            slide_stop_time: 3.0,
            roll_objects: [1, 2],
            roll_shapes: vec![ShapeKind::Cylinder, ShapeKind::Cone, ShapeKind::Mug],
            roll_speed: [0.2, 1.5],
            collide_air_fraction: 0.5,
            collide_speed: [2.5, 5.0],
            collide_air_time: [0.5, 0.8],
            collide_air_clearance: [0.5, 1.5],
            collide_offset: 0.3,
            collide_floor_gap: [2.0, 3.5],
            collide_spin: 2.0,
            stack_boxes: [2, 4],
            stack_scale: [0.5, 0.8],
            projectile_scale: [1.0, 1.4],
            projectile_speed: [5.0, 9.0],
            projectile_distance: 3.0,
            projectile_aim: [0.2, 0.8],
            push_objects: [1, 3],
            push_gap: [0.1, 0.6],
            push_turn: 0.5,
            push_lateral: 0.3,
            pusher_scale: [0.3, 0.5],
            push_clearance: 0.01,
            push_approach: [0.1, 0.5],
            push_speed: [0.5, 1.5],
            push_ramp: 0.5,
            push_tail: 8.0,
            push_jitter: 0.0,
        }
    }

    /// These parameters with their objects' materials drawn as `materials` says.
    pub fn with_materials(mut self, materials: Materials) -> Self {
        self.material_ranges = match materials {
            Materials::Kubric => None,
            Materials::Uniform => Some(MaterialRanges::UNIFORM),
        };
        self
    }

    /// Generator name: the scenario's own name, or `physics-mix` for several.
    pub fn name(&self) -> &'static str {
        match self.scenarios.as_slice() {
            [one] => one.name(),
            _ => "physics-mix",
        }
    }

    /// Checks every list is non-empty, every range ordered and gravity pointing down.
    pub(crate) fn validate(&self) -> Result<()> {
        let bad = |what: &str| Err(SimError::Invalid(format!("scenario parameters: {what}")));
        if self.scenarios.is_empty() {
            return bad("no scenario");
        }
        if self.shapes.is_empty()
            || self.materials.is_empty()
            || self.rest_shapes.is_empty()
            || self.floor_shapes.is_empty()
        {
            return bad("empty shape or material list");
        }
        if self
            .floor_shapes
            .iter()
            .chain(&self.rest_shapes)
            .any(|k| !self.shapes.contains(k))
            || !self.shapes.contains(&ShapeKind::Cube)
        {
            return bad("floor and rest shapes and the cube must be in the shape list");
        }
        // Roll shapes matter only where roll scenes are drawn.
        if self.scenarios.contains(&Scenario::Roll)
            && (self.roll_shapes.is_empty()
                || self.roll_shapes.iter().any(|k| !self.shapes.contains(k)))
        {
            return bad("roll shapes must be a non-empty part of the shape list");
        }
        if self.rest_variants.is_empty() {
            return bad("no rest variant");
        }
        let ranges = [
            self.rest_singles,
            self.tower_boxes,
            self.pile_objects,
            self.slide_objects,
            self.stack_boxes,
            self.push_objects,
            self.roll_objects,
        ];
        if ranges.iter().any(|r| r[0] == 0 || r[0] > r[1]) {
            return bad("an object-count range is empty or starts at 0");
        }
        let spans = [
            self.scale,
            self.tower_scale,
            self.drop_height,
            self.slide_speed,
            self.collide_speed,
            self.collide_air_time,
            self.collide_air_clearance,
            self.collide_floor_gap,
            self.stack_scale,
            self.projectile_scale,
            self.projectile_speed,
            self.projectile_aim,
            self.push_gap,
            self.pusher_scale,
            self.push_approach,
            self.push_speed,
            self.roll_speed,
        ];
        if spans
            .iter()
            .any(|r| !(r[0].is_finite() && r[1].is_finite() && r[0] > 0.0 && r[0] <= r[1]))
        {
            return bad("a range is empty, not positive or not finite");
        }
        if let Some(m) = &self.material_ranges {
            m.validate()?;
        }
        if !(self.push_jitter.is_finite() && self.push_jitter >= 0.0) {
            return bad("push_jitter must be finite and non-negative");
        }
        if !(0.0..=1.0).contains(&self.collide_air_fraction) {
            return bad("collide_air_fraction must be in [0, 1]");
        }
        if self.gravity[2].is_nan() || self.gravity[2] >= 0.0 {
            return bad("gravity must point down (negative z)");
        }
        Ok(())
    }
}
