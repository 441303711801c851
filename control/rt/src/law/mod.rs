pub mod delay;
pub mod guided_friction;
pub mod inner_estimate;
pub mod outer_loop;
pub mod rest_hold;
