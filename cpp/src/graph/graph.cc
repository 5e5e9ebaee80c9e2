#include "marionette/graph/graph.h"

#include <algorithm>
#include <functional>
#include <sstream>
#include <unordered_set>

namespace marionette::graph {

struct Graph::Topology {
  int64_t version = 0;
  std::vector<std::shared_ptr<Entity>> entities;
  std::unordered_map<std::string, Entity*> by_name;
  bool profiling = false;
  std::vector<const PollHook*> polls;    // run first, every tick
  std::vector<StateSlot*> states;        // committed after every tick
  std::vector<const UpdateHook*> hooks;  // run every tick
  int num_signals = 0;
};

namespace {

using SourceOf = std::function<const SignalBase*(const InputSignalBase&)>;

std::string ShapeString(const SignalBase& s) {
  const Shape shape = s.shape();
  return std::string(s.type_name()) + " " + std::to_string(shape.rows) + "x" +
         std::to_string(shape.cols);
}

/// Finds one dependency cycle among the signals, or returns an empty path. Edges: a computed
/// output depends on its prerequisites; an input on the output it is plugged to. Source and
/// state outputs end every path (their value is known at the start of a tick).
std::vector<const SignalBase*> FindCycle(const std::vector<std::shared_ptr<Entity>>& entities,
                                         const SourceOf& source_of) {
  enum Color { kWhite, kGrey, kBlack };
  std::unordered_map<const SignalBase*, Color> color;
  std::vector<const SignalBase*> stack;
  std::vector<const SignalBase*> cycle;

  std::function<bool(const SignalBase*)> visit = [&](const SignalBase* s) -> bool {
    Color& c = color[s];
    if (c == kBlack) return false;
    if (c == kGrey) {
      auto it = std::find(stack.begin(), stack.end(), s);
      cycle.assign(it, stack.end());
      cycle.push_back(s);
      return true;
    }
    c = kGrey;
    stack.push_back(s);
    std::vector<const SignalBase*> next;
    if (s->is_input()) {
      if (const SignalBase* src = source_of(static_cast<const InputSignalBase&>(*s))) {
        next.push_back(src);
      }
    } else if (s->kind() == SignalKind::kOutput) {
      next = s->prerequisites();
    }
    for (const SignalBase* n : next) {
      if (visit(n)) return true;
    }
    stack.pop_back();
    color[s] = kBlack;
    return false;
  };

  for (const auto& e : entities) {
    for (const auto& s : e->signals()) {
      if (visit(s.get())) return cycle;
    }
  }
  return {};
}

/// Validates a set of entities with the given plugs; throws GraphError listing every problem.
void Validate(const std::vector<std::shared_ptr<Entity>>& entities, const SourceOf& source_of) {
  std::vector<std::string> errors;
  std::unordered_set<const Entity*> members;
  std::unordered_set<std::string> names;
  for (const auto& e : entities) {
    members.insert(e.get());
    if (!names.insert(e->name()).second) {
      errors.push_back("two entities are called '" + e->name() + "'");
    }
  }
  auto outside = [&](const SignalBase* s) { return members.count(&s->owner()) == 0; };

  for (const auto& e : entities) {
    for (InputSignalBase* in : e->inputs()) {
      const SignalBase* src = source_of(*in);
      if (src == nullptr && !in->has_fixed_value()) {
        errors.push_back("input " + in->full_name() + " (" + ShapeString(*in) +
                         ") is neither plugged nor set");
      } else if (src != nullptr && outside(src)) {
        errors.push_back("input " + in->full_name() + " is plugged to " + src->full_name() +
                         ", but entity '" + src->owner().name() + "' is not in the graph");
      }
    }
    for (const UpdateHook& hook : e->update_hooks()) {
      for (const SignalBase* p : hook.prerequisites) {
        if (outside(p)) {
          errors.push_back("update '" + hook.name + "' of entity '" + e->name() + "' reads " +
                           p->full_name() + ", but entity '" + p->owner().name() +
                           "' is not in the graph");
        }
      }
    }
  }
  if (errors.empty()) {
    const std::vector<const SignalBase*> cycle = FindCycle(entities, source_of);
    if (!cycle.empty()) {
      std::string path;
      for (const SignalBase* s : cycle) path += (path.empty() ? "" : " <- ") + s->full_name();
      errors.push_back("dependency cycle (each signal needs the next): " + path);
    }
  }
  if (!errors.empty()) {
    std::string message = "invalid graph:";
    for (const std::string& e : errors) message += "\n  - " + e;
    throw GraphError(message);
  }
}

std::unique_ptr<Graph::Topology> MakeTopology(std::vector<std::shared_ptr<Entity>> entities,
                                              int64_t version) {
  auto topo = std::make_unique<Graph::Topology>();
  topo->version = version;
  topo->entities = std::move(entities);
  for (const auto& e : topo->entities) {
    topo->by_name.emplace(e->name(), e.get());
    topo->num_signals += static_cast<int>(e->signals().size());
    for (const auto& s : e->states()) topo->states.push_back(s.get());
    for (const UpdateHook& h : e->update_hooks()) topo->hooks.push_back(&h);
    for (const PollHook& p : e->poll_hooks()) topo->polls.push_back(&p);
  }
  return topo;
}

const SignalBase* CurrentSource(const InputSignalBase& in) { return in.source(); }

std::pair<std::string_view, std::string_view> SplitFullName(std::string_view full_name) {
  const size_t dot = full_name.find('.');
  if (dot == std::string_view::npos || dot == 0 || dot + 1 == full_name.size()) {
    throw GraphError("'" + std::string(full_name) +
                     "' is not a signal name of the form "
                     "'entity.signal'");
  }
  return {full_name.substr(0, dot), full_name.substr(dot + 1)};
}

std::string DotEscape(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (std::string_view("{}|<>\" ").find(c) != std::string_view::npos) out += '\\';
    out += c;
  }
  return out;
}

std::string FixedValueLabel(const InputSignalBase& in) {
  const Shape shape = in.shape();
  if (!in.has_fixed_value() || shape.size() > 4) return "";
  std::vector<double> v(shape.size());
  in.Flatten(v.data());
  std::ostringstream os;
  os.precision(3);
  os << " =";
  for (double x : v) os << ' ' << x;
  return os.str();
}

}  // namespace

// ---- Graph --------------------------------------------------------------------------------------

Graph::Graph(std::unique_ptr<Topology> topology) : topology_(std::move(topology)) {}
Graph::~Graph() = default;

namespace {
EntityTiming* TimingOf(bool profiling, Entity* e) {
  return profiling ? &e->mutable_timing() : nullptr;
}

void AttachTimings(const std::vector<std::shared_ptr<Entity>>& entities, bool on) {
  for (const auto& e : entities) {
    for (const auto& s : e->signals()) s->set_timing(on ? &e->mutable_timing() : nullptr);
  }
}
}  // namespace

void Graph::Evaluate(const Tick& t) {
  Topology& topo = *topology_;
  const bool p = topo.profiling;
  // Phase 0: data from outside the graph enters it.
  for (const PollHook* h : topo.polls) {
    ProfileScope scope(TimingOf(p, h->owner));
    h->run(t);
  }
  // Phase 1: everything reads the values of tick t (pulling computes what is needed, once).
  for (StateSlot* s : topo.states) {
    ProfileScope scope(TimingOf(p, &s->signal().mutable_owner()));
    s->ComputeNext(t);
  }
  for (const UpdateHook* h : topo.hooks) {
    ProfileScope scope(TimingOf(p, h->owner));
    h->run(t);
  }
  // Phase 2: states move to t + 1.
  for (StateSlot* s : topo.states) s->Commit();
  if (p) {
    for (const auto& e : topo.entities) {
      EntityTiming& timing = e->mutable_timing();
      timing.window.Add(timing.tick_ns);
      const bool over = timing.budget_ns > 0.0 && timing.tick_ns > timing.budget_ns;
      timing.overruns += over ? 1 : 0;
      timing.consecutive_overruns = over ? timing.consecutive_overruns + 1 : 0;
      timing.last_tick_over = over;
      timing.tick_ns = 0.0;
    }
  }
}

void Graph::SetProfiling(bool on) {
  topology_->profiling = on;
  AttachTimings(topology_->entities, on);
}

bool Graph::profiling() const { return topology_->profiling; }

int Graph::LastOverruns(std::vector<const Entity*>* out) const {
  out->clear();
  for (const auto& e : topology_->entities) {
    if (e->timing().last_tick_over && out->size() < out->capacity()) out->push_back(e.get());
  }
  return static_cast<int>(out->size());
}

const std::vector<std::shared_ptr<Entity>>& Graph::entities() const { return topology_->entities; }

Entity* Graph::FindEntity(std::string_view name) const {
  auto it = topology_->by_name.find(std::string(name));
  return it == topology_->by_name.end() ? nullptr : it->second;
}

Entity& Graph::entity(std::string_view name) const {
  if (Entity* e = FindEntity(name)) return *e;
  std::string known;
  for (const auto& e : topology_->entities) known += (known.empty() ? "" : ", ") + e->name();
  throw GraphError("no entity '" + std::string(name) + "' in the graph; entities: " + known);
}

SignalBase* Graph::FindSignal(std::string_view full_name) const {
  const size_t dot = full_name.find('.');
  if (dot == std::string_view::npos) return nullptr;
  Entity* e = FindEntity(full_name.substr(0, dot));
  return e == nullptr ? nullptr : e->FindSignal(full_name.substr(dot + 1));
}

SignalBase& Graph::signal(std::string_view full_name) const {
  const auto [entity_name, signal_name] = SplitFullName(full_name);
  return entity(entity_name).signal(signal_name);
}

int Graph::num_signals() const { return topology_->num_signals; }

int64_t Graph::version() const { return topology_->version; }

std::string Graph::ToDot() const {
  std::ostringstream os;
  os << "digraph marionette {\n  rankdir=LR;\n  node [shape=record, fontsize=10];\n";
  for (const auto& e : topology_->entities) {
    std::string ins, outs;
    for (const auto& s : e->signals()) {
      const std::string port = "<" + s->name() + "> " + DotEscape(s->name());
      if (s->is_input()) {
        const auto& in = static_cast<const InputSignalBase&>(*s);
        ins += (ins.empty() ? "" : "|") + port +
               (in.is_plugged() ? "" : DotEscape(FixedValueLabel(in)));
      } else {
        const char* suffix = s->kind() == SignalKind::kState    ? "\\ (state)"
                             : s->kind() == SignalKind::kSource ? "\\ (source)"
                                                                : "";
        outs += (outs.empty() ? "" : "|") + port + suffix;
      }
    }
    os << "  \"" << e->name() << "\" [label=\"{{" << ins << "}|" << DotEscape(e->name()) << "\\n"
       << e->type_name() << "|{" << outs << "}}\"];\n";
  }
  for (const auto& e : topology_->entities) {
    for (InputSignalBase* in : e->inputs()) {
      if (const SignalBase* src = in->source()) {
        os << "  \"" << src->owner().name() << "\":\"" << src->name() << "\":e -> \"" << e->name()
           << "\":\"" << in->name() << "\":w;\n";
      }
    }
  }
  os << "}\n";
  return os.str();
}

bool Graph::Apply(GraphEdit* edit) {
  if (edit == nullptr || !edit->prepared() || edit->base_version_ != topology_->version) {
    return false;
  }
  for (auto& [input, source] : edit->replugs_) input->PlugFrom(*source);
  edit->retired_topology_ = std::move(topology_);
  topology_ = std::move(edit->prepared_topology_);
  return true;
}

// ---- GraphBuilder -------------------------------------------------------------------------------

GraphBuilder::GraphBuilder() = default;
GraphBuilder::~GraphBuilder() = default;

Entity& GraphBuilder::AddShared(std::shared_ptr<Entity> entity) {
  if (FindEntity(entity->name()) != nullptr) {
    throw GraphError("an entity called '" + entity->name() + "' was already added");
  }
  entities_.push_back(std::move(entity));
  return *entities_.back();
}

Entity* GraphBuilder::FindEntity(std::string_view name) const {
  for (const auto& e : entities_) {
    if (e->name() == name) return e.get();
  }
  return nullptr;
}

SignalBase& GraphBuilder::Resolve(std::string_view full_name) const {
  const auto [entity_name, signal_name] = SplitFullName(full_name);
  Entity* e = FindEntity(entity_name);
  if (e == nullptr) throw GraphError("no entity '" + std::string(entity_name) + "' was added");
  return e->signal(signal_name);
}

void GraphBuilder::Connect(SignalBase& from, SignalBase& to) {
  for (const SignalBase* s : {&from, &to}) {
    if (FindEntity(s->owner().name()) != &s->owner()) {
      throw GraphError("cannot plug " + s->full_name() + ": entity '" + s->owner().name() +
                       "' was not added to this builder");
    }
  }
  CheckPluggable(from, to);
  auto& input = static_cast<InputSignalBase&>(to);
  if (input.is_plugged()) {
    throw GraphError("input " + input.full_name() + " is already plugged to " +
                     input.source()->full_name() + "; an input has exactly one source");
  }
  input.PlugFrom(from);
}

void GraphBuilder::Connect(std::string_view from, std::string_view to) {
  Connect(Resolve(from), Resolve(to));
}

std::unique_ptr<Graph> GraphBuilder::Build() {
  Validate(entities_, CurrentSource);
  auto graph = std::unique_ptr<Graph>(new Graph(MakeTopology(std::move(entities_), 1)));
  entities_.clear();
  return graph;
}

// ---- GraphEdit ----------------------------------------------------------------------------------

GraphEdit::GraphEdit(const Graph& graph)
    : base_version_(graph.version()),
      base_profiling_(graph.profiling()),
      entities_(graph.entities()) {}

GraphEdit::~GraphEdit() = default;

Entity& GraphEdit::AddShared(std::shared_ptr<Entity> entity) {
  if (FindEntity(entity->name()) != nullptr) {
    throw GraphError("an entity called '" + entity->name() + "' is already in the graph");
  }
  new_entities_.push_back(entity);
  entities_.push_back(std::move(entity));
  prepared_topology_.reset();
  return *entities_.back();
}

void GraphEdit::Remove(std::string_view name) {
  auto it = std::find_if(entities_.begin(), entities_.end(),
                         [&](const auto& e) { return e->name() == name; });
  if (it == entities_.end()) {
    throw GraphError("cannot remove '" + std::string(name) + "': no such entity");
  }
  entities_.erase(it);
  prepared_topology_.reset();
}

Entity* GraphEdit::FindEntity(std::string_view name) const {
  for (const auto& e : entities_) {
    if (e->name() == name) return e.get();
  }
  return nullptr;
}

bool GraphEdit::IsNew(const Entity& e) const {
  return std::any_of(new_entities_.begin(), new_entities_.end(),
                     [&](const auto& n) { return n.get() == &e; });
}

SignalBase& GraphEdit::Resolve(std::string_view full_name) const {
  const auto [entity_name, signal_name] = SplitFullName(full_name);
  Entity* e = FindEntity(entity_name);
  if (e == nullptr) throw GraphError("no entity '" + std::string(entity_name) + "' in the edit");
  return e->signal(signal_name);
}

void GraphEdit::Connect(SignalBase& from, SignalBase& to) {
  for (const SignalBase* s : {&from, &to}) {
    if (FindEntity(s->owner().name()) != &s->owner()) {
      throw GraphError("cannot plug " + s->full_name() + ": entity '" + s->owner().name() +
                       "' is not in the edited graph");
    }
  }
  CheckPluggable(from, to);
  auto& input = static_cast<InputSignalBase&>(to);
  if (IsNew(input.owner())) {
    input.PlugFrom(from);
  } else {
    auto it = std::find_if(replugs_.begin(), replugs_.end(),
                           [&](const auto& r) { return r.first == &input; });
    if (it != replugs_.end()) {
      it->second = &from;
    } else {
      replugs_.emplace_back(&input, &from);
    }
  }
  prepared_topology_.reset();
}

void GraphEdit::Connect(std::string_view from, std::string_view to) {
  Connect(Resolve(from), Resolve(to));
}

void GraphEdit::Prepare() {
  const auto source_of = [this](const InputSignalBase& in) -> const SignalBase* {
    for (const auto& [input, source] : replugs_) {
      if (input == &in) return source;
    }
    return in.source();
  };
  Validate(entities_, source_of);
  prepared_topology_ = MakeTopology(entities_, base_version_ + 1);
  prepared_topology_->profiling = base_profiling_;
  AttachTimings(new_entities_, base_profiling_);
}

void RunTicks(Graph& graph, Tick* t, int64_t n) {
  for (int64_t i = 0; i < n; ++i, ++*t) graph.Evaluate(*t);
}

}  // namespace marionette::graph
