//! Loading a model: the checks of a parsed model file ([`DriveModel::from_file`]) and
//! the index built from it.

use std::collections::BTreeMap;
use std::ops::RangeInclusive;

use super::fields::*;
use super::*;

impl DriveModel {
    /// Checks a parsed model file and builds the model.
    pub fn from_file(f: &ModelFile) -> Result<Self, ModelError> {
        let m = f.model.as_str();
        let invalid = |problem: String| ModelError::Invalid {
            model: m.to_string(),
            path: String::new(),
            problem,
        };
        let at = |path: &str, problem: String| ModelError::Invalid {
            model: m.to_string(),
            path: path.to_string(),
            problem,
        };
        let v2 = match f.schema_version {
            1 => false,
            2 => true,
            n => {
                return Err(at(
                    "schema_version",
                    format!("{n} is not supported (1 and 2 are)"),
                ))
            }
        };
        let id_ok = valid_model_id(m);
        if !id_ok {
            return Err(at("model", format!("{m:?} is not an id: {MODEL_ID_RULE}")));
        }
        if !v2 {
            if let Some(path) = v1_required(f).first() {
                return Err(at(
                    path,
                    "schema_version 1 requires this field (version 2 makes it optional)"
                        .to_string(),
                ));
            }
            if f.blocks.is_some() || f.naming.is_some() {
                return Err(at(
                    if f.blocks.is_some() {
                        "blocks"
                    } else {
                        "naming"
                    },
                    "is a schema_version 2 field".to_string(),
                ));
            }
        }
        let mut absent: Vec<String> = Vec::new();
        // Modes: v1 both, in this order; v2 any non-empty subset without repeats.
        let mut modes = Vec::new();
        for (i, s) in f.modes.iter().enumerate() {
            let mode = match s.as_str() {
                "rtu" => Mode::Rtu,
                "ascii" => Mode::Ascii,
                other => {
                    return Err(at(
                        &format!("modes[{i}]"),
                        format!("{other:?} is not \"rtu\" or \"ascii\""),
                    ))
                }
            };
            if modes.contains(&mode) {
                return Err(at(&format!("modes[{i}]"), format!("{s:?} is listed twice")));
            }
            modes.push(mode);
        }
        if modes.is_empty() || (!v2 && f.modes != ["rtu", "ascii"]) {
            return Err(at(
                "modes",
                if v2 {
                    "must list at least one of \"rtu\", \"ascii\"".to_string()
                } else {
                    format!(
                        "schema_version 1 requires [\"rtu\", \"ascii\"], found {:?}",
                        f.modes
                    )
                },
            ));
        }
        let (broadcast, first, last, addresses_fact) = match &f.addresses {
            Some(a) => {
                let broadcast = hex8(m, "addresses.broadcast", &a.broadcast)?;
                let first = hex8(m, "addresses.first", &a.first)?;
                let last = hex8(m, "addresses.last", &a.last)?;
                check_fact(m, "addresses", &a.fact)?;
                (broadcast, first, last, Fact::from_file(&a.fact))
            }
            None => (
                0,
                1,
                0xF7,
                spec("Modbus over Serial Line V1.02 2.2: 1..247, 0 broadcast"),
            ),
        };
        if broadcast != 0 || first == 0 || first > last {
            return Err(at("addresses", format!(
                "broadcast must be 00 and 01 <= first <= last, found {broadcast:02X} {first:02X}..{last:02X}"
            )));
        }
        let mut functions = Vec::new();
        for (i, c) in f.functions.codes.iter().enumerate() {
            functions.push(hex8(m, &format!("functions.codes[{i}]"), c)?);
        }
        check_fact(m, "functions", &f.functions.fact)?;
        let mut exception_codes = Vec::new();
        for (i, e) in f.exception_codes.iter().flatten().enumerate() {
            exception_codes.push((
                hex8(m, &format!("exception_codes[{i}].code"), &e.code)?,
                e.meaning.clone(),
            ));
        }
        if exception_codes.is_empty() {
            absent.push("exception_codes".to_string());
        }
        let no_rules = BTreeMap::new();
        let rules = f.exceptions.as_ref().unwrap_or(&no_rules);
        let mut exceptions = BTreeMap::new();
        for fault in Fault::ALL {
            let path = format!("exceptions.{}", fault.key());
            match rules.get(fault.key()) {
                Some(rule) => {
                    let code = hex8(m, &format!("{path}.code"), &rule.code)?;
                    if !exception_codes.iter().any(|(c, _)| *c == code) {
                        return Err(at(
                            &format!("{path}.code"),
                            format!("code {code:02X} is not in the exception-code table"),
                        ));
                    }
                    check_fact(m, &path, &rule.fact)?;
                    exceptions.insert(
                        fault,
                        ExceptionRule {
                            code,
                            fact: Fact::from_file(&rule.fact),
                        },
                    );
                }
                None if fault == Fault::NoAccess => {}
                None if v2 => absent.push(path),
                None => return Err(at("exceptions", format!("no rule for {}", fault.key()))),
            }
        }
        let kinds = Fault::ALL.map(Fault::key);
        if let Some((path, problem)) =
            unknown_key(rules, &kinds, "exceptions", ("fault kind", "kinds"))
        {
            return Err(at(&path, problem));
        }
        let no_silence = BTreeMap::new();
        let silences = f.silence.as_ref().unwrap_or(&no_silence);
        let mut silence = BTreeMap::new();
        for r in SilenceReason::ALL {
            let path = format!("silence.{}", r.key());
            match silences.get(r.key()) {
                Some(fact) => {
                    check_fact(m, &path, fact)?;
                    silence.insert(r, Fact::from_file(fact));
                }
                None if v2 => absent.push(path),
                None => return Err(at("silence", format!("no entry for {}", r.key()))),
            }
        }
        let reasons = SilenceReason::ALL.map(SilenceReason::key);
        if let Some((path, problem)) =
            unknown_key(silences, &reasons, "silence", ("reason", "reasons"))
        {
            return Err(at(&path, problem));
        }

        let no_limits = file::LimitsFile {
            max_frame_bytes: None,
            read_registers: None,
            write_registers: None,
            same_group: None,
            response_time_ms: None,
        };
        let l = f.limits.as_ref().unwrap_or(&no_limits);
        for (what, fact) in [
            (
                "limits.max_frame_bytes",
                l.max_frame_bytes.as_ref().map(|v| &v.fact),
            ),
            (
                "limits.read_registers",
                l.read_registers.as_ref().map(|v| &v.fact),
            ),
            (
                "limits.write_registers",
                l.write_registers.as_ref().map(|v| &v.fact),
            ),
            ("limits.same_group", l.same_group.as_ref().map(|v| &v.fact)),
            (
                "limits.response_time_ms",
                l.response_time_ms.as_ref().map(|v| &v.fact),
            ),
        ] {
            if let Some(fact) = fact {
                check_fact(m, what, fact)?;
            }
        }
        // A count is stated for each mode the description serves; a mode it does not
        // serve takes the specification's, which nothing sends in that mode reads.
        for (p, what) in [
            (&l.read_registers, "limits.read_registers"),
            (&l.write_registers, "limits.write_registers"),
        ] {
            if let Some(p) = p {
                for &mode in &modes {
                    let stated = match mode {
                        Mode::Rtu => p.rtu.is_some(),
                        Mode::Ascii => p.ascii.is_some(),
                    };
                    if !stated {
                        return Err(at(
                            &format!("{what}.{mode}"),
                            format!("no count for {mode}, a mode the description serves"),
                        ));
                    }
                }
            }
        }
        let per_mode = |p: &Option<file::PerModeFile>, n: u16| match p {
            Some(p) => PerMode {
                rtu: p.rtu.unwrap_or(n),
                ascii: p.ascii.unwrap_or(n),
                fact: Fact::from_file(&p.fact),
            },
            None => PerMode {
                rtu: n,
                ascii: n,
                fact: spec(SPEC_COUNTS),
            },
        };
        let limits = Limits {
            max_frame: l.max_frame_bytes.as_ref().map_or(256, |v| v.value),
            max_frame_fact: l.max_frame_bytes.as_ref().map_or_else(
                || spec("Modbus over Serial Line V1.02 2.5.1: an RTU frame is at most 256 bytes, an ASCII frame 513 characters"),
                |v| Fact::from_file(&v.fact),
            ),
            read: per_mode(&l.read_registers, 125),
            write: per_mode(&l.write_registers, 123),
            same_group: l.same_group.as_ref().is_some_and(|v| v.value),
            same_group_fact: l.same_group.as_ref().map_or_else(
                || spec("Modbus application protocol V1.1b3: a request may span any registers the device serves"),
                |v| Fact::from_file(&v.fact),
            ),
            response_time_ms: l.response_time_ms.as_ref().map(|v| v.value),
            response_time_fact: l.response_time_ms.as_ref().map(|v| Fact::from_file(&v.fact)),
            max_frame_ascii: l.max_frame_bytes.is_none().then_some(513),
        };
        if l.response_time_ms.is_none() {
            absent.push("limits.response_time_ms".to_string());
        }
        // Counts must fit the frame: the derivation the legacy note confirms.
        for &mode in &modes {
            let r = limits.read.get(mode);
            let w = limits.write.get(mode);
            let read_len = read_response_len(mode, r);
            let write_len = write_request_len(mode, w);
            let max = limits.max_frame_in(mode);
            if r == 0 || read_len > max {
                return Err(at(
                    &format!("limits.read_registers.{mode}"),
                    format!(
                        "{r} registers need a {read_len}-byte response, over the {max}-byte frame"
                    ),
                ));
            }
            if w == 0 || write_len > max {
                return Err(at(
                    &format!("limits.write_registers.{mode}"),
                    format!(
                        "{w} registers need a {write_len}-byte request, over the {max}-byte frame"
                    ),
                ));
            }
        }

        // Groups: command and monitor first, then parameter groups, then examples.
        let mut groups = Vec::new();
        for (i, g) in f.groups.iter().flatten().enumerate() {
            let first = hex16(m, &format!("groups[{i}].first"), &g.first)?;
            let last = hex16(m, &format!("groups[{i}].last"), &g.last)?;
            if first > last {
                return Err(at(
                    &format!("groups[{i}].last"),
                    format!("{last:04X} is before first {first:04X}"),
                ));
            }
            groups.push(Group {
                name: g.name.clone(),
                parameter_group: None,
                span: first..=last,
                registers: vec![],
                no_access: vec![],
                source: String::new(),
                notes: vec![],
            });
        }
        let mut map: Vec<(RangeInclusive<u16>, Access, usize, Origin)> = Vec::new();
        let mut named = Vec::new();
        let mut bits = BitRoles::default();
        let mut external_fault_code = None;
        for r in f.registers.iter().flatten() {
            let register = hex16(m, "registers.register", &r.register)?;
            let access = Access::parse(&r.access).ok_or_else(|| {
                invalid(format!(
                    "register {register:04X}: access {:?} is not read-write, read-only or reserved",
                    r.access
                ))
            })?;
            let role = match &r.role {
                Some(s) => Some(Role::parse(s).ok_or_else(|| {
                    invalid(format!("register {register:04X}: unknown role {s:?}"))
                })?),
                None => None,
            };
            let group = groups
                .iter()
                .position(|g| g.span.contains(&register))
                .ok_or_else(|| invalid(format!("register {register:04X} is in no group")))?;
            let fact = match (&r.source, r.basis) {
                (Some(s), None) => Fact::documented(s),
                (source, Some(basis)) => {
                    let ff = file::FactFile {
                        basis,
                        source: source.clone(),
                        rule: None,
                        why: r.why.clone(),
                        request: None,
                        reply: None,
                    };
                    check_fact(m, &format!("register {register:04X}"), &ff)?;
                    Fact::from_file(&ff)
                }
                (None, None) => {
                    return Err(invalid(format!(
                        "register {register:04X}: needs a source or a basis"
                    )))
                }
            };
            let max = match &r.max {
                Some(b) => {
                    check_fact(m, &format!("register {register:04X} max"), &b.fact)?;
                    Some((
                        hex16(m, "registers.max", &b.value)?,
                        Fact::from_file(&b.fact),
                    ))
                }
                None => None,
            };
            let resolution = match &r.resolution {
                Some(res) => {
                    check_fact(m, &format!("register {register:04X} resolution"), &res.fact)?;
                    check_fact(
                        m,
                        &format!("register {register:04X} resolution handling"),
                        &res.handling,
                    )?;
                    if res.step < 2 {
                        return Err(invalid(format!(
                            "register {register:04X}: resolution step {} must be 2 or more",
                            res.step
                        )));
                    }
                    Some(Resolution {
                        above: hex16(m, "registers.resolution.above", &res.above)?,
                        step: res.step,
                        fact: Fact::from_file(&res.fact),
                        lines: res.lines.clone(),
                        handling: Fact::from_file(&res.handling),
                    })
                }
                None => None,
            };
            if (max.is_some() || resolution.is_some()) && access != Access::ReadWrite {
                return Err(invalid(format!(
                    "register {register:04X}: a max or resolution needs a read-write register"
                )));
            }
            if let Some(code) = &r.external_fault_code {
                check_fact(m, "external_fault_code", &code.fact)?;
                external_fault_code = Some((code.value, Fact::from_file(&code.fact)));
            }
            for b in &r.bits {
                if b.bit > 15 {
                    return Err(invalid(format!(
                        "register {register:04X}: bit {} is over 15",
                        b.bit
                    )));
                }
                let slot = match (role, b.role.as_deref()) {
                    (_, None) => continue,
                    (Some(Role::Operation), Some("run")) => &mut bits.run,
                    (Some(Role::Operation), Some("reverse")) => &mut bits.reverse,
                    (Some(Role::Operation), Some("external-fault")) => &mut bits.external_fault,
                    (Some(Role::Operation), Some("fault-reset")) => &mut bits.fault_reset,
                    (Some(Role::Status), Some("running")) => &mut bits.running,
                    (Some(Role::Status), Some("reverse")) => &mut bits.status_reverse,
                    (Some(Role::Status), Some("ready")) => &mut bits.ready,
                    (Some(Role::Status), Some("fault")) => &mut bits.fault,
                    (_, Some(other)) => {
                        return Err(invalid(format!(
                            "register {register:04X}: bit role {other:?} is not known for this register"
                        )))
                    }
                };
                *slot = Some(b.bit);
            }
            map.push((register..=register, access, group, Origin::Named));
            named.push(NamedRegister {
                register,
                name: r.name.clone(),
                access,
                role,
                max,
                max_lines: r.max.as_ref().and_then(|b| b.lines.clone()),
                max_notes: r.max.as_ref().map(|b| b.notes.clone()).unwrap_or_default(),
                resolution,
                fact,
                bits: r
                    .bits
                    .iter()
                    .map(|b| NamedBit {
                        bit: b.bit,
                        name: b.name.clone(),
                    })
                    .collect(),
            });
        }
        for g in groups.iter_mut() {
            let regs: Vec<u16> = named
                .iter()
                .filter(|n| g.span.contains(&n.register))
                .map(|n| n.register)
                .collect();
            if regs.len() != g.span.clone().count() {
                return Err(invalid(format!(
                    "group {}: {} named registers for a span of {} ({:04X}..{:04X}); every register of the block must be listed",
                    g.name,
                    regs.len(),
                    g.span.clone().count(),
                    g.span.start(),
                    g.span.end()
                )));
            }
            g.registers = vec![g.span.clone()];
            g.source = named
                .iter()
                .find(|n| n.register == *g.span.start())
                .and_then(|n| n.fact.source.clone())
                .unwrap_or_default();
        }
        let parameter_groups = f.parameter_groups.as_deref().unwrap_or_default();
        let uses_naming = !parameter_groups.is_empty()
            || f.parameter_access
                .as_ref()
                .is_some_and(|p| !p.read_only.is_empty());
        let naming = match &f.naming {
            Some(n) => {
                if n.rule != "group-number" {
                    return Err(at(
                        "naming.rule",
                        format!("{:?} is not a known rule (\"group-number\" is)", n.rule),
                    ));
                }
                check_fact(m, "naming", &n.fact)?;
                Some(Fact::from_file(&n.fact))
            }
            None if !v2 => Some(Fact::documented(
                "the manual's parameter tables: register = group x 100H + number",
            )),
            None if uses_naming => {
                return Err(at(
                    "naming",
                    "parameter_groups and parameter_access.read_only number registers as group x 100H + number: state the rule ({\"rule\": \"group-number\", ...})".to_string(),
                ))
            }
            None => None,
        };
        for p in parameter_groups {
            let idx = groups.len();
            let mut registers = Vec::new();
            for r in &p.registers {
                registers.push(hex_range(m, "parameter_groups.registers", r)?);
            }
            let mut no_access = Vec::new();
            for r in &p.no_access {
                no_access.push(hex_range(m, "parameter_groups.no_access", r)?);
            }
            for r in registers.iter().chain(&no_access) {
                if (*r.start() >> 8) as u8 != p.group || (*r.end() >> 8) as u8 != p.group {
                    return Err(invalid(format!(
                        "parameter group {}: {:04X}..{:04X} is outside the group (register = group x 100H + number)",
                        p.group,
                        r.start(),
                        r.end()
                    )));
                }
            }
            for r in &registers {
                map.push((r.clone(), Access::ReadWrite, idx, Origin::Parameter));
            }
            for r in &no_access {
                map.push((r.clone(), Access::NoAccess, idx, Origin::Parameter));
            }
            let lo = registers.iter().chain(&no_access).map(|r| *r.start()).min();
            let hi = registers.iter().chain(&no_access).map(|r| *r.end()).max();
            let (Some(lo), Some(hi)) = (lo, hi) else {
                return Err(invalid(format!(
                    "parameter group {}: no registers",
                    p.group
                )));
            };
            groups.push(Group {
                name: format!("group {}", p.group),
                parameter_group: Some(p.group),
                span: lo..=hi,
                registers,
                no_access,
                source: p.source.clone(),
                notes: p.notes.clone(),
            });
        }
        // Blocks (v2): plain ranges, each a group of the map.
        let mut blocks = Vec::new();
        for (i, b) in f.blocks.iter().flatten().enumerate() {
            let path = format!("blocks[{i}]");
            let first = hex16(m, &format!("{path}.first"), &b.first)?;
            let last = hex16(m, &format!("{path}.last"), &b.last)?;
            if first > last {
                return Err(at(
                    &format!("{path}.last"),
                    format!("{last:04X} is before first {first:04X}"),
                ));
            }
            let access = match b.access.as_deref() {
                None => Access::ReadWrite,
                Some(s) => Access::parse(s)
                    .filter(|a| *a != Access::NoAccess)
                    .ok_or_else(|| {
                        at(
                            &format!("{path}.access"),
                            format!("{s:?} is not read-write, read-only, write-only or reserved"),
                        )
                    })?,
            };
            let min = b
                .min
                .as_deref()
                .map(|v| hex16(m, &format!("{path}.min"), v))
                .transpose()?;
            let max = b
                .max
                .as_deref()
                .map(|v| hex16(m, &format!("{path}.max"), v))
                .transpose()?;
            if let (Some(lo), Some(hi)) = (min, max) {
                if lo > hi {
                    return Err(at(
                        &format!("{path}.max"),
                        format!("{hi:04X} is below min {lo:04X}"),
                    ));
                }
            }
            if (min.is_some() || max.is_some())
                && !matches!(access, Access::ReadWrite | Access::WriteOnly)
            {
                return Err(at(
                    &format!("{path}.access"),
                    "min and max bound written values: the block must be read-write or write-only"
                        .to_string(),
                ));
            }
            if let Some(scale) = b.scale {
                if !scale.is_finite() || scale == 0.0 {
                    return Err(at(
                        &format!("{path}.scale"),
                        format!("{scale} is not a finite non-zero number"),
                    ));
                }
            }
            check_fact(m, &path, &b.fact)?;
            let block = Block {
                span: first..=last,
                name: b.name.clone(),
                access,
                min,
                max,
                unit: b.unit.clone(),
                scale: b.scale,
                fact: Fact::from_file(&b.fact),
            };
            // A reserved block is served by no function: it stays out of the map, and a
            // request for it gets the illegal-register answer.
            if access != Access::Reserved {
                let idx = groups.len();
                groups.push(Group {
                    name: b
                        .name
                        .clone()
                        .unwrap_or_else(|| format!("block {first:04X}")),
                    parameter_group: None,
                    span: first..=last,
                    registers: vec![first..=last],
                    no_access: vec![],
                    source: block.fact.citation(),
                    notes: vec![],
                });
                map.push((first..=last, access, idx, Origin::Block));
            }
            blocks.push(block);
        }
        let mut example_registers = Vec::new();
        for e in f.example_registers.iter().flatten() {
            let register = hex16(m, "example_registers.register", &e.register)?;
            let initial = hex16(m, "example_registers.initial", &e.initial)?;
            let access = Access::parse(&e.access)
                .filter(|a| matches!(a, Access::ReadWrite | Access::ReadOnly))
                .ok_or_else(|| {
                    invalid(format!(
                        "example register {register:04X}: access must be read-write or read-only"
                    ))
                })?;
            check_fact(m, "example_registers", &e.fact)?;
            // v2: an example register inside a block whose access agrees is the block's
            // register (a description copied from a built-in model keeps it harmlessly;
            // `model lint` warns).
            if let Some(b) = blocks.iter().find(|b| b.span.contains(&register)) {
                if v2 && b.access == access {
                    example_registers.push((register, initial, access, Fact::from_file(&e.fact)));
                    continue;
                }
            }
            let idx = groups.len();
            groups.push(Group {
                name: format!("example {register:04X}"),
                parameter_group: None,
                span: register..=register,
                registers: vec![register..=register],
                no_access: vec![],
                source: e.fact.citation_text(),
                notes: vec![],
            });
            map.push((register..=register, access, idx, Origin::Example));
            example_registers.push((register, initial, access, Fact::from_file(&e.fact)));
        }
        map.sort_by_key(|(r, ..)| *r.start());
        for w in map.windows(2) {
            if w[0].0.end() >= w[1].0.start() {
                return Err(invalid(format!(
                    "registers {:04X}..{:04X} and {:04X}..{:04X} overlap",
                    w[0].0.start(),
                    w[0].0.end(),
                    w[1].0.start(),
                    w[1].0.end()
                )));
            }
        }
        let mut aliases = Vec::new();
        for a in f.aliases.iter().flatten() {
            let first = hex16(m, "aliases.first", &a.first)?;
            let last = hex16(m, "aliases.last", &a.last)?;
            let target = hex16(m, "aliases.target", &a.target)?;
            check_fact(m, "aliases", &a.fact)?;
            if first > last || u32::from(target) + u32::from(last - first) > 0xFFFF {
                return Err(invalid(format!(
                    "alias {first:04X}..{last:04X} -> {target:04X} is out of range"
                )));
            }
            aliases.push(Alias {
                span: first..=last,
                target,
                fact: Fact::from_file(&a.fact),
            });
        }
        let identification = match &f.identification {
            None => {
                absent.push("identification".to_string());
                None
            }
            Some(id) => {
                check_fact(m, "identification", &id.fact)?;
                Some(Identification {
                    register: id
                        .register
                        .as_deref()
                        .map(|r| hex16(m, "identification.register", r))
                        .transpose()?,
                    value: id
                        .value
                        .as_deref()
                        .map(|r| hex16(m, "identification.value", r))
                        .transpose()?,
                    simulated: match (&id.value, &id.simulated) {
                        (Some(v), _) | (None, Some(v)) => hex16(m, "identification", v)?,
                        (None, None) => 0,
                    },
                    fact: Fact::from_file(&id.fact),
                })
            }
        };
        let mut initial_values = Vec::new();
        for v in f.initial_values.iter().flatten() {
            check_fact(m, "initial_values", &v.fact)?;
            initial_values.push((
                hex16(m, "initial_values.register", &v.register)?,
                hex16(m, "initial_values.value", &v.value)?,
                Fact::from_file(&v.fact),
            ));
        }
        let parameter_access = match &f.parameter_access {
            Some(p) => {
                check_fact(m, "parameter_access", &p.fact)?;
                Fact::from_file(&p.fact)
            }
            None => Fact {
                basis: Basis::Decision,
                source: None,
                rule: None,
                why: Some("not stated: every register of the map is taken as read-write unless its block says otherwise".to_string()),
            },
        };
        if let Some(lb) = &f.loop_back {
            check_fact(m, "loop_back", &lb.fact)?;
            check_fact(m, "loop_back.other_test_codes", &lb.other_test_codes)?;
        } else {
            absent.push("loop_back".to_string());
        }

        let mut model = DriveModel {
            id: f.model.clone(),
            version: f.schema_version,
            modes,
            title: f.title.clone(),
            manual: f.manual.clone().unwrap_or_else(|| f.title.clone()),
            broadcast,
            addresses: first..=last,
            addresses_fact,
            functions,
            functions_fact: Fact::from_file(&f.functions.fact),
            loop_back_data_bytes: f.loop_back.as_ref().map_or(2, |l| l.data_bytes),
            loop_back_fact: f.loop_back.as_ref().map(|l| Fact::from_file(&l.fact)),
            loop_back_other_fact: f
                .loop_back
                .as_ref()
                .map(|l| Fact::from_file(&l.other_test_codes)),
            exception_codes,
            exception_codes_source: f.exception_codes_source.clone(),
            exceptions,
            silence,
            limits,
            groups,
            named,
            bits,
            external_fault_code,
            identification,
            parameter_access,
            parameter_read_only: Vec::new(),
            example_registers,
            initial_values,
            aliases,
            source: Source::default(),
            blocks,
            naming,
            absent,
            map,
        };
        if let Some(p) = &f.parameter_access {
            model.parameter_read_only = read_only_parameters(&model, &p.read_only)?;
        }
        for (r, ..) in &model.initial_values {
            if model.lookup(*r).is_none() {
                return Err(invalid(format!(
                    "initial value for {r:04X}, which is not in the map"
                )));
            }
        }
        if let Some(r) = model.identification.as_ref().and_then(|i| i.register) {
            match model.lookup(r) {
                None => {
                    return Err(at(
                        "identification.register",
                        format!("{r:04X} is not in the map"),
                    ))
                }
                Some(i) if i.access == Access::WriteOnly => {
                    return Err(at(
                        "identification.register",
                        format!("{r:04X} is write-only: it cannot be read"),
                    ))
                }
                Some(_) => {}
            }
        }
        Ok(model)
    }
}

impl file::FactFile {
    fn citation_text(&self) -> String {
        Fact::from_file(self).citation()
    }
}

/// Checks the read-only entries against the map built so far: every register a listed
/// parameter (not "-"), the parameter numbers spelling the same registers, no overlaps.
fn read_only_parameters(
    model: &DriveModel,
    entries: &[file::ReadOnlyParameterFile],
) -> Result<Vec<ReadOnlyParameter>, ModelError> {
    let m = model.id.as_str();
    let invalid = |problem: String| ModelError::Invalid {
        model: m.to_string(),
        path: String::new(),
        problem,
    };
    let mut out: Vec<ReadOnlyParameter> = Vec::new();
    for e in entries {
        let what = format!("parameter_access.read_only {}", e.registers);
        let registers = hex_range(m, "parameter_access.read_only.registers", &e.registers)?;
        check_fact(m, &what, &e.fact)?;
        let (a, b) = match e.parameters.split_once("..") {
            Some((a, b)) => (a, b),
            None => (e.parameters.as_str(), e.parameters.as_str()),
        };
        let spelled = parameter_number(a)
            .zip(parameter_number(b))
            .map(|((ga, na), (gb, nb))| {
                (u16::from(ga) << 8 | u16::from(na))..=(u16::from(gb) << 8 | u16::from(nb))
            });
        if spelled.as_ref() != Some(&registers) {
            return Err(invalid(format!(
                "{what}: parameters {:?} are not registers {:04X}..{:04X} (register = group x 100H + number)",
                e.parameters,
                registers.start(),
                registers.end()
            )));
        }
        for r in registers.clone() {
            let i = model.map.partition_point(|(x, ..)| *x.end() < r);
            match model.map.get(i) {
                Some((x, Access::ReadWrite, _, Origin::Parameter)) if x.contains(&r) => {}
                _ => {
                    return Err(invalid(format!(
                        "{what}: {r:04X}H is not a listed parameter register of the map"
                    )))
                }
            }
        }
        if let Some(o) = out.iter().find(|o| {
            o.registers.start() <= registers.end() && registers.start() <= o.registers.end()
        }) {
            return Err(invalid(format!("{what}: overlaps {}", o.parameters)));
        }
        out.push(ReadOnlyParameter {
            registers,
            parameters: e.parameters.clone(),
            fact: Fact::from_file(&e.fact),
            lines: e.lines.clone(),
        });
    }
    Ok(out)
}

/// The first key of a table in `section` that is none of `known`, as the error's path and
/// problem ("unknown reason \"x\"; the reasons are a, b"): a misspelt key is refused, not
/// ignored.
fn unknown_key<V>(
    table: &BTreeMap<String, V>,
    known: &[&str],
    section: &str,
    (what, whats): (&str, &str),
) -> Option<(String, String)> {
    let k = table.keys().find(|k| !known.contains(&k.as_str()))?;
    Some((
        format!("{section}.{k}"),
        format!("unknown {what} {k:?}; the {whats} are {}", known.join(", ")),
    ))
}
