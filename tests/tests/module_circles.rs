//! No module circles in any crate of the workspace (DECISIONS.md "Server layout" and
//! "Load tester and client layout"): for every module, the graph over its child
//! modules has no cycle ([`tessera_e2e::module_circles`] says what an edge is). Test
//! code is left out of the crates' check: a test may use any sibling it checks
//! against.

#![allow(clippy::unwrap_used)] // a failed unwrap is a failed test

use std::path::Path;
use tessera_e2e::module_circles::{TestCode, circles};

/// Every crate's `src/`: the contract, the server, the client and the tools.
const CRATES: [&str; 7] = [
    "shared", "charts", "server", "client", "proxy", "bench", "tests",
];

#[test]
fn no_module_imports_a_sibling_that_imports_it_back() {
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let mut found = Vec::new();
    for krate in CRATES {
        for circle in circles(&workspace.join(krate).join("src"), TestCode::Excluded) {
            found.push(format!("{krate}/src: {circle}"));
        }
    }
    assert!(
        found.is_empty(),
        "module circles (a cycle among the children of one module):\n{}",
        found.join("\n")
    );
}

/// The server's structure holds with its test code counted too.
#[test]
fn the_server_has_no_circles_even_through_its_tests() {
    let server = Path::new(env!("CARGO_MANIFEST_DIR")).join("../server/src");
    let found = circles(&server, TestCode::Included);
    assert!(found.is_empty(), "{}", found.join("\n"));
}

/// The circle finder finds the circles it should, and leaves out what it should.
#[test]
fn a_circle_between_siblings_is_found_and_a_parent_edge_is_not() {
    let dir = tempfile::tempdir().unwrap();
    let write = |rel: &str, text: &str| {
        let p = dir.path().join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    };
    write("lib.rs", "pub mod a;\npub mod b;\npub mod c;\n");
    write("a.rs", "use crate::b::{self, X};\n// use crate::c;\n");
    write("b/mod.rs", "pub mod inner;\npub use inner::Y;\n");
    write("b/inner.rs", "use super::super::c::Z;\nuse super::Y;\n");
    write(
        "c.rs",
        "fn f() { let s = \"crate::a::g\"; } // crate::a::g()\n",
    );
    // A binary beside the library is another crate.
    write("bin/tool.rs", "use tessera::c;\n");
    assert_eq!(
        circles(dir.path(), TestCode::Included),
        Vec::<String>::new(),
        "no cycle yet"
    );

    // Test code closes the circle: found when it counts, not when it does not.
    write(
        "c.rs",
        "fn f() {}\n#[cfg(test)]\nmod tests {\n    fn g() { crate::a::g(); }\n}\n",
    );
    let found = circles(dir.path(), TestCode::Included);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].starts_with("crate: {a, b, c}"), "{}", found[0]);
    assert_eq!(
        circles(dir.path(), TestCode::Excluded),
        Vec::<String>::new()
    );

    // …and so does a test module in a file of its own, declared `#[cfg(test)] mod`.
    write(
        "c.rs",
        "fn f() {}\n#[cfg(test)]\nmod checks;\npub fn h() {}\n",
    );
    write("c/checks.rs", "use crate::a::g;\n");
    assert_eq!(circles(dir.path(), TestCode::Included).len(), 1);
    assert_eq!(
        circles(dir.path(), TestCode::Excluded),
        Vec::<String>::new()
    );

    // Production code always counts.
    write("c.rs", "pub fn f() { crate::a::g(); }\n");
    let found = circles(dir.path(), TestCode::Excluded);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].contains("c -> a: c.rs:1"), "{}", found[0]);
}
