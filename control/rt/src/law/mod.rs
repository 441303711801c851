pub mod delay;
pub mod guided_friction;
pub mod rest_hold;
