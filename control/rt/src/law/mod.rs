pub mod outer_loop;
