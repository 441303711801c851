//! The control law's per-cycle pieces: eq. (21) and the adaptation of its gains
//! (outer_loop), the Smith predictor over the command delay (delay), the rest hold
//! (rest_hold), the friction ramp's guided switch (guided_friction), the online inner-loop
//! estimate (inner_estimate), constrained guiding's fixtures (guide), the sensorless admittance (admittance), the zero-moment
//! law's cycle over them (zero_moment), and a built plan played one command a cycle (plan_play).

pub mod admittance;
pub mod delay;
pub mod guide;
pub mod guided_friction;
pub mod inner_estimate;
pub mod outer_loop;
pub mod plan_play;
pub mod rest_hold;
pub mod zero_moment;
